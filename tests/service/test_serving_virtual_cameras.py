"""The service on a file with virtual cameras: each robot camera's image at its own size and under its own name."""

from __future__ import annotations

from pathlib import Path

import cv2
import httpx
import numpy as np
from service_live import multipart, serve, settings_for

from fisheye_infer import Detector
from fisheye_infer.cameras.camera_models import ExtendedUnified
from fisheye_infer.cameras.rig import Rig
from fisheye_infer.export.rebake import rebake
from fisheye_infer.runtime.artifact import read_meta
from fisheye_infer.scenes.render import Renderer, random_scene


def test_detect_takes_each_camera_at_its_own_size(small_model: Path, tmp_path: Path) -> None:
    rig = read_meta(small_model).rig
    eucm = ExtendedUnified(width=200, height=150, fx=37.0, fy=37.0, cx=99.5, cy=74.5, alpha=0.61, beta=1.07, fov=220.0)
    cameras = [c.model_copy(update={"name": f"cam{i}"}) for i, c in enumerate(rig.cameras)]
    cameras[1] = cameras[1].model_copy(update={"model": eucm})
    robot = Rig(name="robot", cameras=tuple(cameras))
    path = tmp_path / "robot.onnx"
    rebake(small_model, robot, path)
    frame = Renderer(texture_seed=2).render(robot, random_scene(np.random.default_rng(4)))
    pngs = {name: cv2.imencode(".png", image)[1].tobytes() for name, image in frame.items()}
    detector = Detector(path, threads=1)
    expected = detector.detect(frame)
    for live in serve(settings_for(path), detector):
        answer = httpx.post(f"{live.url}/detect", files=multipart(pngs), timeout=30)
        assert answer.status_code == 200, answer.text
        body = answer.json()
        assert body["cameras_used"] == ["cam0", "cam1", "cam2", "cam3"]
        assert len(body["detections"]) == len(expected)
        wrong = {**pngs, "cam1": pngs["cam0"]}  # 160x160 where cam1 is 200x150
        refused = httpx.post(f"{live.url}/detect", files=multipart(wrong), timeout=30)
        assert refused.status_code == 422 and "cam1" in refused.text and "200x150" in refused.text
