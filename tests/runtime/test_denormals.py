"""Denormal floats flushed to zero while a session runs, and only then (``fisheye_infer.runtime.denormals``)."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from fisheye_infer.runtime.denormals import FLUSHES, flushed_denormals
from fisheye_infer.runtime.session import create_session, session_options

pytestmark = pytest.mark.skipif(not FLUSHES, reason="flushing denormals is implemented for Linux x86-64")

TINY = np.float32(1e-30)
SCALE = np.float32(1e-10)  # TINY * SCALE = 1e-40, below float32's smallest normal number (1.18e-38)


def _product() -> np.float32:
    return (np.array([TINY], np.float32) * SCALE)[0]


def _scaling_model(path: Path) -> Path:
    """A graph that multiplies its input by ``SCALE``."""
    graph = helper.make_graph(
        [helper.make_node("Mul", ["x", "scale"], ["y"])],
        "scale",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [64])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [64])],
        [numpy_helper.from_array(np.array([SCALE], np.float32), "scale")],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    model.ir_version = 8
    onnx.save(model, path)
    return path


def test_flushed_inside_the_block_and_restored_after() -> None:
    assert _product() > 0  # a denormal result is kept outside
    with flushed_denormals():
        assert _product() == 0
        with flushed_denormals():
            assert _product() == 0
        assert _product() == 0  # the inner block restores the outer one's environment
    assert _product() > 0


def test_each_thread_its_own() -> None:
    seen: dict[str, np.float32] = {}
    inside, checked = threading.Event(), threading.Event()

    def other() -> None:
        with flushed_denormals():
            inside.set()
            checked.wait(10)
            seen["inside"] = _product()
        seen["after"] = _product()

    thread = threading.Thread(target=other)
    thread.start()
    assert inside.wait(10)
    seen["main, meanwhile"] = _product()
    checked.set()
    thread.join(10)
    assert seen["inside"] == 0 and seen["after"] > 0 and seen["main, meanwhile"] > 0


def test_session_runs_flushed_on_the_calling_thread(tmp_path: Path) -> None:
    session = create_session(_scaling_model(tmp_path / "scale.onnx"), threads=1)
    x = np.full(64, TINY, np.float32)
    assert np.all(session.run(None, {"x": x})[0] > 0)
    with flushed_denormals():
        assert np.all(session.run(None, {"x": x})[0] == 0)


def test_worker_threads_asked_to_flush() -> None:
    assert session_options(2).get_session_config_entry("session.set_denormal_as_zero") == "1"


def test_building_a_processs_first_session_leaves_the_thread_as_it_was(tmp_path: Path) -> None:
    """ONNX Runtime flushes, for good, the thread that builds a process's first session asking for it; a fresh
    process, so that this session is the first."""
    model = _scaling_model(tmp_path / "scale.onnx")
    script = (
        "import numpy as np\n"
        "from fisheye_infer.runtime.session import create_session\n"
        f"create_session({str(model)!r}, threads=1)\n"
        "print(float((np.array([1e-30], np.float32) * np.float32(1e-10))[0]) > 0)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120, check=True)
    assert done.stdout.strip().splitlines()[-1] == "True"
