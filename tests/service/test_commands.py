"""``fisheye-infer serve`` without the web stack: help still works, running says how to install it."""

from __future__ import annotations

import subprocess
import sys

BLOCK_WEB = """
import importlib.abc, sys
class Block(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name.split('.')[0] in {'fastapi', 'uvicorn', 'starlette', 'prometheus_client', 'pydantic_settings', 'websockets'}:
            raise ImportError(f'No module named {name!r}')
sys.meta_path.insert(0, Block())
from fisheye_infer.cli import main
"""


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    code = BLOCK_WEB + f"sys.exit(main({list(args)!r}))"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)


def test_help_needs_no_web_stack() -> None:
    result = _cli("serve", "--help")
    assert result.returncode == 0 and "--queue-size" in result.stdout and "--microbatch-max-size" in result.stdout


def test_missing_extra_says_how_to_install_it() -> None:
    result = _cli("serve", "model.onnx")
    assert result.returncode == 1
    assert "pip install 'fisheye-infer[serve]'" in result.stderr and "fastapi" in result.stderr
