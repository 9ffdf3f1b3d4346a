# Set-up and the two jobs of the Quick start. Every target installs what it needs first.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install demo test lint bench clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	# torch first, pinned: this CPU build is what the export extra is developed against
	$(BIN)/pip install torch==2.13.0
	# ray and triton: the Ray Serve / Ray Data / Triton client paths the tests exercise
	$(BIN)/pip install -e '.[export,serve,dev,ray,triton]'
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/fisheye-infer demo --out artifacts/demo

test: $(STAMP)
	$(BIN)/pytest -q

# ruff over the tree, mypy over the runtime (tests/test_lint.py runs both within `make test`)
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy

# Not part of the tests: speed and ratios on this machine (15-25 min on 2 cores)
bench: $(STAMP)
	$(BIN)/pip install -e '.[export,serve,dev,ray,triton,bench]'
	$(BIN)/python benchmarks/run_all.py

clean:
	rm -rf $(VENV) artifacts build *.egg-info
