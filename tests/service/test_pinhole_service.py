"""The service around a six-camera pinhole model (a reduced pinhole-bevdet): the same routes, the cameras
from the file's metadata."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import httpx
import numpy as np
import pytest
from service_live import LiveServer, multipart, serve, settings_for
from small_configs import small_configs  # noqa: E402

from fisheye_infer.cameras.rig import PINHOLE_CAMERAS
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.scenes.render import Renderer, random_scene

ARCH = "pinhole-bevdet"


@pytest.fixture(scope="module")
def pinhole_model(small_exports) -> tuple[Path, object]:  # noqa: ANN001
    return small_exports(ARCH).onnx, small_configs()[ARCH][1]


@pytest.fixture(scope="module")
def pinhole_detector(pinhole_model: tuple[Path, object]) -> Detector:
    return Detector(pinhole_model[0], threads=1)


@pytest.fixture(scope="module")
def pinhole_images(pinhole_model: tuple[Path, object]) -> dict[str, bytes]:
    frame = Renderer(texture_seed=3).render(pinhole_model[1], random_scene(np.random.default_rng(7)))  # type: ignore[arg-type]
    return {name: cv2.imencode(".png", image)[1].tobytes() for name, image in frame.items()}


@pytest.fixture(scope="module")
def pinhole_client(pinhole_model: tuple[Path, object], pinhole_detector: Detector) -> Iterator[httpx.Client]:
    server: LiveServer
    for server in serve(settings_for(pinhole_model[0]), pinhole_detector):
        with httpx.Client(base_url=server.url, timeout=20.0) as client:
            yield client


def test_model_names_six_pinhole_cameras(pinhole_client: httpx.Client) -> None:
    body = pinhole_client.get("/model").json()
    assert body["cameras"] == list(PINHOLE_CAMERAS) and body["architecture"] == ARCH
    assert body["image_size"] == {"width": 160, "height": 90}


def test_detect_takes_six_parts(
    pinhole_client: httpx.Client, pinhole_images: dict[str, bytes], pinhole_detector: Detector
) -> None:
    response = pinhole_client.post("/detect", files=multipart(pinhole_images))
    assert response.status_code == 200, response.text
    body = response.json()
    reference = pinhole_detector.detect(pinhole_images)
    assert body["cameras_used"] == list(PINHOLE_CAMERAS)
    np.testing.assert_allclose([d["score"] for d in body["detections"]], reference.scores, atol=1e-6)
    batch = pinhole_client.post(
        "/detect/batch", files=multipart(pinhole_images, "0.") + multipart(pinhole_images, "1.")
    )
    assert batch.status_code == 200, batch.text
    assert [f["batch_size"] for f in batch.json()["frames"]] == [2, 2]


def test_a_missing_pinhole_camera_is_named_or_runs_degraded(
    pinhole_client: httpx.Client, pinhole_images: dict[str, bytes]
) -> None:
    five = {c: b for c, b in pinhole_images.items() if c != "nu_rgb_camera_rear"}
    refused = pinhole_client.post("/detect", files=multipart(five))
    assert refused.status_code == 422 and "nu_rgb_camera_rear" in refused.text
    degraded = pinhole_client.post("/detect", files=multipart(five), data={"allow_missing_cameras": "true"})
    assert degraded.status_code == 200, degraded.text
    assert degraded.json()["cameras_used"] == [c for c in PINHOLE_CAMERAS if c != "nu_rgb_camera_rear"]
