# Set-up and the two jobs of the Quick start. Every target installs what it needs first.
PYTHON ?= python3
VENV ?= .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: install demo test test-fast lint docs docs-check bench bench-report clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	# torch first, pinned: this CPU build is what the export extra is developed against
	$(BIN)/pip install torch==2.13.0
	# ray and triton: the Ray Serve / Ray Data / Triton client paths the tests exercise
	$(BIN)/pip install -e '.[export,serve,dev,ray,triton,ros]'
	# a real Triton server for the tests (Linux x86-64, glibc 2.35+): the wheel's bundled tritonserver and Python
	# backend only; --no-deps because its Python package pins numpy below 2 and is not used
	if [ "$$(uname -sm)" = "Linux x86_64" ] && [ "$$(getconf GNU_LIBC_VERSION | awk '{split($$2, v, "."); print (v[1] > 2 || v[2] >= 35)}')" = 1 ]; \
	then $(BIN)/pip install --no-deps nvidia-pytriton==0.7.0; else echo "no Triton server on this platform: its tests skip"; fi
	# TrackEval's HOTA for the tracking evaluation; --no-deps: its declared dependencies add the GUI build of OpenCV
	# beside the headless one
	$(BIN)/pip install --no-deps trackeval==1.3.0
	touch $(STAMP)

install: $(STAMP)

demo: $(STAMP)
	$(BIN)/fisheye-infer demo --out artifacts/demo

# Two workers by default (WORKERS=8 for more), a test file to each in turn; tests/conftest.py hands
# out the longest files first and builds each full-size export once
WORKERS ?= 2
PYTEST := $(BIN)/pytest -q -n $(WORKERS) --dist loadfile --no-loadscope-reorder

test: $(STAMP)
	$(PYTEST)

# The inner loop: all but the slow tests (tests/conftest.py: full-size models, whole exports, Ray)
# and the fresh-install one
test-fast: $(STAMP)
	$(PYTEST) -m "not slow and not install"

# ruff over the tree, mypy over the whole library: the runtime, models, export and service (settings in
# pyproject.toml's [tool.mypy]; tests/test_lint.py runs both within `make test`)
lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy

# The documentation site (docs/, mkdocs.yml) into site/; --strict: a broken link or reference fails
docs: $(STAMP)
	NO_MKDOCS_2_WARNING=1 $(BIN)/mkdocs build --strict --site-dir site

# The built site in headless Chromium (Debian: apt install chromium): no sideways scroll, no overflowing table,
# every picture loads, no page too tall (tests/test_docs_browser.py; skipped where no browser is installed)
docs-check: $(STAMP)
	$(BIN)/pytest -q -p no:xdist tests/test_docs_browser.py

# Not part of the tests: every benchmark on this machine, each writing a JSON result under benchmarks/results/,
# then docs/performance/ generated from them. `make bench BENCH_ARGS=--quick` for the short runs.
BENCH_ARGS ?=
bench: $(STAMP)
	$(BIN)/pip install -e '.[export,serve,dev,ray,triton,ros,bench]'
	$(BIN)/python benchmarks/run_all.py $(BENCH_ARGS)

# docs/performance/, the figures and the charts generated again from the results under benchmarks/results/
bench-report: $(STAMP)
	$(BIN)/python benchmarks/report.py

clean:
	rm -rf $(VENV) artifacts build *.egg-info
