"""The wide-angle camera models of robot calibration tools: double sphere, EUCM/UCM, Mei's omnidirectional
model and OpenCV's distorted pinhole, against independent computations of their published definitions."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from pydantic import ValidationError

from fisheye_infer.cameras.camera_models import (
    DistortedPinhole,
    DoubleSphere,
    ExtendedUnified,
    KannalaBrandt,
    Omnidirectional,
)
from fisheye_infer.cameras.rig import RigCamera

#: Basalt's test intrinsics (``test/src/test_camera.cpp``) for its double sphere and EUCM cameras.
BASALT_DS = {"fx": 0.5 * 805, "fy": 0.5 * 800, "cx": 505.0, "cy": 509.0, "xi": 0.5 * -0.150694, "alpha": 0.5 * 1.48785}
BASALT_EUCM = {"fx": 460.76484651566468, "fy": 459.4051018049483, "cx": 365.8937161309615, "cy": 249.33499869752445,
               "alpha": 0.5903365915227143, "beta": 1.127468196965374}  # fmt: skip


def _rays(max_deg: float, n: int = 400, seed: int = 0) -> np.ndarray:
    """Rays at incidence angles up to ``max_deg`` in every direction, at distances 0.5-20 m."""
    rng = np.random.default_rng(seed)
    a, b = rng.uniform(0, math.radians(max_deg), n), rng.uniform(-math.pi, math.pi, n)
    unit = np.stack([np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), np.cos(a)], axis=-1)
    return unit * rng.uniform(0.5, 20.0, (n, 1))


def _unit(p: np.ndarray) -> np.ndarray:
    return p / np.linalg.norm(p, axis=1, keepdims=True)


def _k(fx: float, fy: float, cx: float, cy: float) -> np.ndarray:
    return np.array([[fx, 0, cx], [0, fy, cy], [0, 0, 1.0]])


def test_double_sphere_is_two_spheres_then_a_shifted_pinhole() -> None:
    """The paper's construction, step by step: unit sphere, shift by xi, second unit sphere, pinhole shifted
    by alpha / (1 - alpha) with focal length f / (1 - alpha)."""
    cam = DoubleSphere(**BASALT_DS, width=1024, height=1024, fov=200)
    rays = _rays(100)
    uv, valid = cam.project(rays)
    q = _unit(_unit(rays) + [0, 0, cam.xi])
    shift = cam.alpha / (1 - cam.alpha)
    ref = np.stack(
        [
            cam.fx / (1 - cam.alpha) * q[:, 0] / (q[:, 2] + shift) + cam.cx,
            cam.fy / (1 - cam.alpha) * q[:, 1] / (q[:, 2] + shift) + cam.cy,
        ],
        axis=-1,
    )
    assert valid.sum() > 300 and np.abs(uv[valid] - ref[valid]).max() < 1e-9


def test_eucm_is_an_ellipsoid_then_a_pinhole() -> None:
    """A ray scaled onto the ellipsoid beta (x^2 + y^2) + z^2 = 1, shifted by alpha / (1 - alpha), imaged by a
    pinhole of focal length f / (1 - alpha)."""
    cam = ExtendedUnified(**BASALT_EUCM, width=752, height=480, fov=200)
    rays = _rays(100)
    uv, valid = cam.project(rays)
    e = rays / np.sqrt(cam.beta * (rays[:, 0] ** 2 + rays[:, 1] ** 2) + rays[:, 2] ** 2)[:, None]
    shift = cam.alpha / (1 - cam.alpha)
    ref = np.stack(
        [
            cam.fx / (1 - cam.alpha) * e[:, 0] / (e[:, 2] + shift) + cam.cx,
            cam.fy / (1 - cam.alpha) * e[:, 1] / (e[:, 2] + shift) + cam.cy,
        ],
        axis=-1,
    )
    assert valid.sum() > 100 and np.abs(uv[valid] - ref[valid]).max() < 1e-9


def test_the_unified_model_three_ways() -> None:
    """UCM(alpha) is the double sphere with xi = 0, the EUCM with beta = 1, and Mei's model with
    xi = alpha / (1 - alpha) and f / (1 - alpha)."""
    alpha, f = 0.6, 300.0
    common = {"cx": 399.5, "cy": 399.5, "width": 800, "height": 800, "fov": 200.0}
    ds = DoubleSphere(fx=f, fy=f, xi=0.0, alpha=alpha, **common)
    eucm = ExtendedUnified(fx=f, fy=f, alpha=alpha, beta=1.0, **common)
    mei = Omnidirectional(fx=f / (1 - alpha), fy=f / (1 - alpha), xi=alpha / (1 - alpha), **common)
    rays = _rays(100)
    (a, va), (b, vb), (c, vc) = ds.project(rays), eucm.project(rays), mei.project(rays)
    assert np.array_equal(va, vb) and np.array_equal(va, vc) and va.sum() > 300
    assert np.abs(a - b)[va].max() < 1e-9 and np.abs(a - c)[va].max() < 1e-9


def test_distorted_pinhole_equals_opencv() -> None:
    """``cv2.projectPoints`` with 5 (plumb_bob) and 8 (rational_polynomial) coefficients is the reference."""
    rays = _rays(40)
    for d in ((-0.28, 0.07, 1e-4, -2e-4, 0.01), (0.4, -0.1, 2e-4, 1e-4, 0.02, 0.7, -0.05, 0.03)):
        cam = DistortedPinhole(fx=450.0, fy=452.0, cx=320.0, cy=240.0, distortion=d, width=640, height=480)
        uv, valid = cam.project(rays)
        ref, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), _k(450.0, 452.0, 320.0, 240.0), np.array(d))
        assert valid.sum() > 50 and np.abs(uv - ref.reshape(-1, 2)).max() < 1e-9
        assert np.abs(cam.unproject(uv[valid]) - _unit(rays)[valid]).max() < 1e-8


def test_mei_model_is_opencv_on_the_shifted_sphere() -> None:
    """Kalibr's omni-radtan: the unit-sphere point moved by xi along the axis, through OpenCV's pinhole."""
    d = (-0.2, 0.05, 1e-3, -1e-3)
    cam = Omnidirectional(fx=700.0, fy=705.0, cx=640.0, cy=480.0, xi=0.9, distortion=d, width=1280, height=960, fov=190)
    rays = _rays(95)
    uv, valid = cam.project(rays)
    ref, _ = cv2.projectPoints(_unit(rays) + [0, 0, 0.9], np.zeros(3), np.zeros(3), _k(700, 705, 640, 480), np.array(d))
    assert valid.sum() > 300 and np.abs(uv - ref.reshape(-1, 2))[valid].max() < 1e-9


@pytest.mark.parametrize(
    "cam",
    [
        DoubleSphere(**BASALT_DS, width=1024, height=1024, fov=190),
        ExtendedUnified(**BASALT_EUCM, width=752, height=480, fov=190),
        Omnidirectional(
            fx=700,
            fy=705,
            cx=640,
            cy=480,
            xi=0.9,
            distortion=(-0.2, 0.05, 1e-3, -1e-3),
            width=1280,
            height=960,
            fov=190,
        ),  # fmt: skip
        DistortedPinhole(fx=450, fy=452, cx=320, cy=240, distortion=(-0.28, 0.07, 1e-4, -2e-4), width=640, height=480),
    ],
    ids=lambda cam: cam.type,
)
def test_unproject_inverts_project(cam) -> None:
    rays = _rays(95)
    uv, valid = cam.project(rays)
    assert valid.sum() > 50 and np.abs(cam.unproject(uv[valid]) - _unit(rays)[valid]).max() < 1e-8
    assert isinstance(
        RigCamera.model_validate({"name": "c", "model": cam.model_dump(), "cam2lidar": np.eye(4).tolist()}).model,
        type(cam),
    )


def test_validity_follows_each_models_domain() -> None:
    """Double sphere: rays at z <= -w2 |p| do not project, pixels beyond the image of the sphere unproject to
    NaN; every model: rays beyond its fov do not project."""
    ds = DoubleSphere(fx=300, fy=300, cx=400, cy=400, xi=-0.2, alpha=0.6, width=800, height=800, fov=360)
    w1 = (1 - 0.6) / 0.6
    w2 = (w1 - 0.2) / math.sqrt(2 * w1 * -0.2 + 0.04 + 1)
    limit = math.acos(-w2)
    edge = np.array(
        [[math.sin(limit - 1e-3), 0, math.cos(limit - 1e-3)], [math.sin(limit + 1e-3), 0, math.cos(limit + 1e-3)]]
    )
    _, valid = DoubleSphere(**{**ds.model_dump(), "width": 100000, "height": 100000}).project(edge)
    assert valid.tolist() == [True, False]
    r_max = 1 / math.sqrt(2 * 0.6 - 1)  # alpha > 0.5: the image of the sphere is a disc of this normalised radius
    assert np.isnan(ds.unproject(np.array([[400 + 300 * r_max * 1.01, 400.0]]))).all()
    narrow = DoubleSphere(**{**ds.model_dump(), "fov": 120.0})
    _, valid = narrow.project(np.array([[math.sin(math.radians(59)), 0, math.cos(math.radians(59))],
                                        [math.sin(math.radians(61)), 0, math.cos(math.radians(61))]]))  # fmt: skip
    assert valid.tolist() == [True, False]
    _, behind = DistortedPinhole(fx=1, fy=1, cx=0, cy=0, distortion=(0, 0, 0, 0), width=10, height=10).project(
        np.array([[0.0, 0.0, -1.0]])
    )
    assert not behind.any()


def test_bad_parameters_are_refused_by_name() -> None:
    with pytest.raises(ValidationError, match="alpha"):
        DoubleSphere(fx=300, fy=300, cx=400, cy=400, xi=0.0, alpha=1.5, width=800, height=800)
    with pytest.raises(ValidationError, match="expected 4, 5 or 8 coefficients"):
        DistortedPinhole(fx=1, fy=1, cx=0, cy=0, distortion=(0, 0, 0, 0, 0, 0), width=10, height=10)


def test_kalibr_equidistant_is_opencv_fisheye() -> None:
    """Kalibr's ``pinhole-equi``, ROS's ``equidistant`` and OpenCV's ``cv::fisheye`` share k1..k4:
    ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``; ``KannalaBrandt`` equals
    ``cv2.fisheye.projectPoints`` in front of the camera."""
    k = (0.02, -0.004, 0.001, -0.0002)
    cam = KannalaBrandt(fx=320.0, fy=321.0, cx=399.5, cy=398.5, k=k, width=800, height=800, fov=220.0)
    rays = _rays(85)
    uv, _ = cam.project(rays)
    ref, _ = cv2.fisheye.projectPoints(
        rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), _k(320.0, 321.0, 399.5, 398.5), np.array(k)
    )
    assert np.abs(uv - ref.reshape(-1, 2)).max() < 1e-9
