"""A real ``tritonserver`` (the nvidia-pytriton wheel's) on 127.0.0.1: the Python-backend repository served, the
project's client over HTTP and gRPC against it, Triton's own errors, and the ONNX Runtime form's config parsed."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from fisheye_infer.deploy.triton.repository import TritonOptions, write_repository
from fisheye_infer.deploy.triton.server import TritonServer, free_port, server_unavailable
from fisheye_infer.errors import ArtifactError, InferenceError
from fisheye_infer.runtime.artifact import read_meta
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.scenes.render import Renderer, random_scene

pytest.importorskip("tritonclient.grpc", reason="needs the [triton] extra")
if reason := server_unavailable():
    pytest.skip(reason, allow_module_level=True)
from fisheye_infer.deploy.triton import TritonDetector  # noqa: E402

NAME = "fisheye_small"
#: Long enough that requests sent together are run together by Triton's dynamic batcher.
QUEUE_DELAY_US = 300_000


@pytest.fixture(scope="module")
def server(small_export, tmp_path_factory: pytest.TempPathFactory):
    repository = tmp_path_factory.mktemp("triton-repository")
    options = TritonOptions(name=NAME, backend="python", max_batch_size=2, max_queue_delay_us=QUEUE_DELAY_US, threads=1)
    write_repository(small_export.onnx, repository, options)
    with TritonServer(repository) as running:
        yield running
    assert running.process is not None and running.process.poll() is not None


@pytest.fixture(scope="module")
def detector(small_export) -> Detector:
    return Detector(small_export.onnx, threads=1)


@pytest.fixture(scope="module")
def frames(small_export) -> list[dict[str, np.ndarray]]:
    rig = read_meta(small_export.onnx).rig
    renderer = Renderer(texture_seed=0)
    return [renderer.render(rig, random_scene(np.random.default_rng(300 + i))) for i in range(3)]


def _assert_same(a, b) -> None:
    """Same boxes: one file, one ONNX Runtime version, one thread each side."""
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_allclose(a.boxes, b.boxes, atol=1e-5)
    np.testing.assert_allclose(a.scores, b.scores, atol=1e-6)


@pytest.mark.parametrize("protocol", ["http", "grpc"])
def test_the_real_server_gives_the_detectors_boxes(server: TritonServer, detector: Detector, frames, protocol) -> None:
    url = server.http_url if protocol == "http" else server.grpc_url
    remote = TritonDetector(url, NAME, protocol=protocol)
    assert remote.info.model_id == detector.info.model_id and remote.max_batch_size == 2
    got = remote.detect(frames[0])
    assert len(got) > 0
    _assert_same(got, detector.detect(frames[0]))
    three = dict(list(frames[1].items())[:3])  # a camera missing travels as camera_valid
    batch = [frames[1], three, frames[2]]  # three frames: split into runs of max_batch_size (2)
    for a, b in zip(remote.detect_batch(batch), detector.detect_batch(batch)):
        _assert_same(a, b)


def test_requests_sent_together_run_as_one_batch(server: TritonServer, detector: Detector, frames) -> None:
    remote = TritonDetector(server.grpc_url, NAME, protocol="grpc")
    stats_url = f"http://{server.http_url}/v2/models/{NAME}/stats"

    def counts() -> tuple[int, int]:
        with urllib.request.urlopen(stats_url, timeout=10) as answer:
            stats = json.load(answer)["model_stats"][0]
        return int(stats["inference_count"]), int(stats["execution_count"])

    before = counts()
    start = threading.Barrier(2)
    results: dict[int, object] = {}

    def send(i: int) -> None:
        start.wait()
        results[i] = remote.detect(frames[i])

    threads = [threading.Thread(target=send, args=(i,)) for i in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(60)
    for i in range(2):
        _assert_same(results[i], detector.detect(frames[i]))
    inferences, executions = (a - b for a, b in zip(counts(), before))
    assert (inferences, executions) == (2, 1)  # two frames, one run of the model


@pytest.mark.parametrize("protocol", ["http", "grpc"])
def test_malformed_requests_get_tritons_error_reported_clearly(server: TritonServer, protocol) -> None:
    url = server.http_url if protocol == "http" else server.grpc_url
    remote = TritonDetector(url, NAME, protocol=protocol)
    n, (w, h) = len(remote.info.cameras), remote.info.image_size
    valid = np.ones((1, n), bool)
    with pytest.raises(InferenceError, match=rf"model '{NAME}' at .*images"):
        remote._infer(np.zeros((1, n, h + 1, w, 3), np.uint8), valid)  # Triton's shape check
    with pytest.raises(InferenceError, match=r"camera_valid"):
        remote._infer(np.zeros((1, n, h, w, 3), np.uint8), np.ones((1, n + 1), bool))
    with pytest.raises(InferenceError, match=r"batch"):
        remote._infer(np.zeros((3, n, h, w, 3), np.uint8), np.ones((3, n), bool))  # above max_batch_size
    with pytest.raises(ArtifactError, match="nope"):
        TritonDetector(url, "nope", protocol=protocol)
    assert remote.detect(list(np.zeros((n, h, w, 3), np.uint8))).boxes.shape[1] == 7  # still serving


def test_the_onnxruntime_form_parses_and_only_its_backend_is_missing(small_export, tmp_path: Path) -> None:
    """Triton's own parser reads the ONNX Runtime form's config.pbtxt: the only failure is the absent backend."""
    write_repository(small_export.onnx, tmp_path, TritonOptions(name="ort_form", kind="cpu", instances=2))
    server = TritonServer(tmp_path, exit_on_error=False).start()
    try:
        request = urllib.request.Request(f"http://{server.http_url}/v2/repository/index", data=b"{}", method="POST")
        with urllib.request.urlopen(request, timeout=10) as answer:
            (entry,) = json.load(answer)
        assert entry["name"] == "ort_form" and entry["state"] == "UNAVAILABLE"
        assert "backend" in entry["reason"] and "onnxruntime" in entry["reason"], entry["reason"]
        assert "pbtxt" not in entry["reason"] and "parse" not in entry["reason"].lower(), entry["reason"]
        pid = server.process.pid if server.process else -1
    finally:
        server.stop()
    with pytest.raises(ProcessLookupError):  # stopped by its PID, and reaped
        os.kill(pid, 0)


def test_cli_serve_runs_until_interrupted(small_export, tmp_path: Path) -> None:
    http_port, grpc_port = free_port(), free_port()
    command = [sys.executable, "-m", "fisheye_infer", "triton", str(small_export.onnx), "--out", str(tmp_path)]
    command += [
        "--backend",
        "python",
        "--name",
        NAME,
        "--serve",
        f"--http-port={http_port}",
        f"--grpc-port={grpc_port}",
    ]
    process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and process.poll() is None:
            line = process.stdout.readline() if process.stdout else ""
            if line.startswith("serving"):
                break
        assert process.poll() is None, process.stdout.read() if process.stdout else ""
        remote = TritonDetector(f"127.0.0.1:{http_port}", NAME)
        assert remote.info.cameras == read_meta(small_export.onnx).cameras
        process.send_signal(signal.SIGINT)
        assert process.wait(60) == 0
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
