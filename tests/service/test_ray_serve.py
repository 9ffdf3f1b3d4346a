"""The service on Ray Serve (local Ray, 2 CPUs, loopback): the Detector's answer, batching across callers, the same refusals."""

from __future__ import annotations

import socket
from collections.abc import Iterator
from concurrent.futures import ThreadPoolExecutor

import httpx
import numpy as np
import pytest
from service_live import multipart, settings_for

from fisheye_infer.runtime.detector import Detector

pytest.importorskip("ray.serve", reason="needs the [ray] extra")


def _free_port() -> int:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


def _metric(text: str, name: str) -> float:
    return sum(
        float(line.split()[-1])
        for line in text.splitlines()
        if line.startswith(name + " ") or line.startswith(name + "{")
    )


@pytest.fixture(scope="module")
def ray_url(ray_local, small_model) -> Iterator[str]:
    """One replica on 1 CPU; batches of up to 4 frames gathered for up to 1 s, so concurrent callers meet."""
    from ray import serve

    from fisheye_infer.service.ray_serve import RayServeOptions, build_app

    port = _free_port()
    serve.start(http_options={"host": "127.0.0.1", "port": port})
    options = RayServeOptions(replicas=1, cpus_per_replica=1, max_batch_size=4, batch_wait_ms=1000)
    serve.run(build_app(settings_for(small_model, queue_size=8), options), name="fisheye-infer", route_prefix="/")
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        serve.shutdown()


def test_four_images_give_the_detectors_answer(ray_url: str, images: dict[str, bytes], detector: Detector) -> None:
    response = httpx.post(f"{ray_url}/detect", files=multipart(images), timeout=60)
    assert response.status_code == 200, response.text
    body = response.json()
    reference = detector.detect(images)
    assert body["model_id"] == detector.info.model_id and body["cameras_used"] == list(detector.info.cameras)
    assert len(body["detections"]) == len(reference) > 0
    np.testing.assert_allclose([d["score"] for d in body["detections"]], reference.scores, atol=1e-6)
    np.testing.assert_allclose(
        [[d[k] for k in ("x", "y", "z_bottom", "l", "w", "h", "yaw")] for d in body["detections"]],
        reference.boxes,
        atol=1e-5,
    )


def test_concurrent_callers_are_batched(
    ray_url: str, images: dict[str, bytes], jpegs: dict[str, bytes], detector: Detector
) -> None:
    before = httpx.get(f"{ray_url}/metrics").text
    frames = [images, jpegs, images, jpegs]
    with ThreadPoolExecutor(len(frames)) as pool:
        responses = list(pool.map(lambda f: httpx.post(f"{ray_url}/detect", files=multipart(f), timeout=60), frames))
    assert [r.status_code for r in responses] == [200] * 4
    for response, frame in zip(responses, frames):  # each caller gets its own frame's boxes back
        np.testing.assert_allclose(
            [d["score"] for d in response.json()["detections"]], detector.detect(frame).scores, atol=1e-6
        )
    after = httpx.get(f"{ray_url}/metrics").text
    runs = _metric(after, "fisheye_serve_batch_frames_count") - _metric(before, "fisheye_serve_batch_frames_count")
    batched = _metric(after, "fisheye_serve_batch_frames_sum") - _metric(before, "fisheye_serve_batch_frames_sum")
    assert batched == 4 and runs < 4  # four frames in fewer runs than callers


def test_health_and_the_plain_services_refusals(ray_url: str, images: dict[str, bytes]) -> None:
    assert httpx.get(f"{ray_url}/healthz").status_code == 200
    assert httpx.get(f"{ray_url}/readyz").json()["status"] == "ready"
    wrong = {"fisheye_camera_top" if c.endswith("front") else c: b for c, b in images.items()}
    response = httpx.post(f"{ray_url}/detect", files=multipart(wrong), timeout=60)
    assert (
        response.status_code == 422
        and "camera 'fisheye_camera_top': not a camera of this model" in response.json()["error"]
    )
    too_big = httpx.post(
        f"{ray_url}/detect", content=b"x" * (1024 * 1024 + 1), headers={"Content-Type": "application/json"}, timeout=60
    )
    assert too_big.status_code == 413 and "max_body_bytes" in too_big.json()["error"]


@pytest.mark.parametrize(
    "options, message",
    [
        ({"replicas": 0}, "replicas: expected at least 1"),
        ({"cpus_per_replica": 0}, "cpus_per_replica: expected a positive number"),
        ({"max_batch_size": 17}, "max_batch_size: expected 1..16"),
    ],
)
def test_bad_options_are_named(options: dict, message: str) -> None:
    from fisheye_infer.service.ray_serve import RayServeOptions

    with pytest.raises(ValueError, match=message):
        RayServeOptions(**options)


def test_serve_ray_refuses_bad_options_before_starting_ray(small_model, capsys: pytest.CaptureFixture[str]) -> None:
    from fisheye_infer.cli import main

    assert main(["serve", str(small_model), "--ray", "--replicas", "0"]) == 1
    assert "replicas: expected at least 1" in capsys.readouterr().err
    # Ray reserves CPUs for its replicas, not GPUs: a provider choice would not reach a GPU there
    assert main(["serve", str(small_model), "--ray", "--providers", "CPUExecutionProvider"]) == 1
    assert "providers: the --ray replicas run on CPU" in capsys.readouterr().err
