"""Real uvicorn servers on 127.0.0.1 (random free ports) around the reduced FisheyeBEVDet export.

``LiveServer`` runs ``build_server(settings, create_app(settings, detector))`` — what
``fisheye-infer serve`` runs — in a thread, on a socket bound to port 0, and stops it at the
end. One Detector (one ONNX Runtime session) is shared by every server of the session.
"""

from __future__ import annotations

from collections.abc import Iterator
from typing import Any

import cv2
import httpx
import numpy as np
import pytest
from service_live import API_KEY, ORIGIN, LiveServer, serve, settings_for

from fisheye_infer.cameras.rig import default_rig
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.scenes.render import Renderer, random_scene, resized_rig


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers",
        "install: builds a fresh virtual environment and pip-installs the package (deselect with -m 'not install')",
    )


@pytest.fixture(scope="session")
def small_model(small_export) -> Any:
    return small_export.onnx


@pytest.fixture(scope="session")
def detector(small_model) -> Detector:
    """One session, one intra-op thread: the other core stays with the server and the clients."""
    return Detector(small_model, threads=1)


@pytest.fixture(scope="session")
def images(detector: Detector) -> dict[str, bytes]:
    """One synthetic frame for the reduced rig, PNG-encoded per camera (~22 kB each)."""
    rig = resized_rig(default_rig(), 0.2)
    frame = Renderer(texture_seed=2).render(rig, random_scene(np.random.default_rng(1)))
    return {name: cv2.imencode(".png", frame[name])[1].tobytes() for name in detector.info.cameras}


@pytest.fixture(scope="session")
def jpegs(detector: Detector) -> dict[str, bytes]:
    rig = resized_rig(default_rig(), 0.2)
    frame = Renderer(texture_seed=5).render(rig, random_scene(np.random.default_rng(5)))
    return {name: cv2.imencode(".jpg", frame[name])[1].tobytes() for name in detector.info.cameras}


@pytest.fixture(scope="session")
def server(small_model, detector: Detector) -> Iterator[LiveServer]:
    """The default service: no key, no micro-batching, a queue of 2, 1 MiB bodies."""
    yield from serve(settings_for(small_model), detector)


@pytest.fixture(scope="session")
def keyed_server(small_model, detector: Detector) -> Iterator[LiveServer]:
    """An API key, /metrics behind it, one CORS origin, and micro-batching of up to 4 frames within 300 ms."""
    yield from serve(
        settings_for(
            small_model,
            api_key=API_KEY,
            metrics_public=False,
            queue_size=8,
            cors_origins=[ORIGIN],
            microbatch_max_size=4,
            microbatch_max_wait_ms=300.0,
        ),
        detector,
    )


@pytest.fixture
def client(server: LiveServer) -> Iterator[httpx.Client]:
    with httpx.Client(base_url=server.url, timeout=20.0) as c:
        yield c
