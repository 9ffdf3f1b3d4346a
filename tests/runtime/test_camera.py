"""Camera models: the OCam test vectors of the spec, OpenCV agreement for Kannala-Brandt,
round trips, the parser's rules and the KB -> OCam fit."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from fisheye_infer.cameras.camera_models import Equidistant, KannalaBrandt, OCamModel, Pinhole
from fisheye_infer.cameras.ocam_fit import fit_ocam_from_kb
from fisheye_infer.errors import CameraModelError


def _ray(alpha_deg: float) -> np.ndarray:
    a = math.radians(alpha_deg)
    return np.array([[math.sin(a), 0.0, math.cos(a)]])


class TestOCamVectors:
    """Spec camera-data-metric.md §1.6, computed from the 1600x1600 sample file."""

    def test_world2cam_doctest_point(self, ocam1600: OCamModel) -> None:
        np.testing.assert_allclose(ocam1600.world2cam(np.array([[1.0, 1.0, 2.0]])), [[1004.8295, 1001.1595]], atol=1e-3)

    def test_optical_axis_maps_to_centre_column_then_row(self, ocam1600: OCamModel) -> None:
        np.testing.assert_allclose(ocam1600.world2cam(np.array([[0.0, 0.0, 2.0]])), [[798.1757, 794.3087]], atol=1e-3)

    def test_behind_on_axis_maps_to_centre_without_fov_test(self) -> None:
        cam = OCamModel.from_file(
            __import__("pathlib").Path(__file__).parents[1] / "data" / "ocam_sample_1600.txt", fov=185
        )
        np.testing.assert_allclose(cam.world2cam(np.array([[0.0, 0.0, -1.0]])), [[cam.center_col, cam.center_row]])

    def test_origin_is_sentinel(self, ocam1600: OCamModel) -> None:
        np.testing.assert_array_equal(ocam1600.world2cam(np.zeros((1, 3))), [[-1.0, -1.0]])

    def test_cam2world_doctest_pixel(self, ocam1600: OCamModel) -> None:
        np.testing.assert_allclose(
            ocam1600.cam2world(np.array([[502.0, 900.0]])), [[-0.5776824, 0.2059931, 0.7898417]], atol=1e-6
        )

    @pytest.mark.parametrize(("alpha", "u"), [(0, 798.1757), (30, 1046.2791), (60, 1305.5427), (90, 1570.5812)])
    def test_incidence_sweep(self, ocam1600: OCamModel, alpha: float, u: float) -> None:
        assert ocam1600.world2cam(_ray(alpha))[0, 0] == pytest.approx(u, abs=1e-3)

    @pytest.mark.parametrize("alpha", [100, 110])
    def test_fov_185_masks_to_sentinel(self, ocam1600: OCamModel, alpha: float) -> None:
        cam = ocam1600.model_copy(update={"fov": 185.0})
        np.testing.assert_array_equal(cam.world2cam(_ray(alpha)), [[-1.0, -1.0]])
        _, valid = cam.project(_ray(alpha))
        assert not valid[0]

    @pytest.mark.parametrize(("fov", "rho"), [(185, 794.447), (220, 952.196)])
    def test_rho_max(self, ocam1600: OCamModel, fov: float, rho: float) -> None:
        cam = ocam1600.model_copy(update={"fov": float(fov)})
        assert float(cam._invpol(np.array([cam.theta_max]))[0]) == pytest.approx(rho, abs=1e-3)

    def test_round_trip_error_is_that_of_two_polynomials(self, ocam1600: OCamModel) -> None:
        back = ocam1600.world2cam(ocam1600.cam2world(np.array([[502.0, 900.0]])))
        np.testing.assert_allclose(back, [[502.0031, 899.9989]], atol=2e-3)


class TestOCamFile:
    def test_reads_the_shipped_calibration(self, ocam800: OCamModel) -> None:
        assert (ocam800.width, ocam800.height) == (800, 800)
        assert (ocam800.center_row, ocam800.center_col) == (398.967516, 399.029971)
        assert ocam800.invpol[0] == 331.189089 and len(ocam800.invpol) == 10 and len(ocam800.pol) == 5

    def test_crlf_and_whitespace_lines_do_not_shift_rows(self, data_dir) -> None:
        text = (data_dir / "ocam_sample_1600.txt").read_text()
        messy = text.replace("\n\n", "\r\n   \r\n").replace("\n", "\r\n")
        assert OCamModel.parse(messy) == OCamModel.parse(text)

    def test_text_round_trip(self, ocam800: OCamModel) -> None:
        assert OCamModel.parse(ocam800.to_text(), fov=ocam800.fov) == ocam800

    @pytest.mark.parametrize(
        ("mutate", "message"),
        [
            (lambda rows: rows[:4], "expected 5 data rows"),
            (lambda rows: ["4 " + rows[0].split(" ", 1)[1]] + rows[1:], "leading count 4"),
            (lambda rows: rows[:2] + ["398.9"] + rows[3:], "centre (row, column): expected 2 numbers"),
            (lambda rows: rows[:3] + ["1 0"] + rows[4:], "affine (c, d, e): expected 3 numbers"),
            (lambda rows: rows[:4] + ["800 abc"], "not a row of numbers"),
            (lambda rows: rows[:4] + ["800.5 800"], "image size must be two positive integers"),
            (lambda rows: rows[:3] + ["1 1 1"] + rows[4:], "affine c - d*e must be non-zero"),
        ],
    )
    def test_malformed_files_name_the_field(self, data_dir, mutate, message: str) -> None:
        rows = [
            r.strip()
            for r in (data_dir / "ocam_sample_1600.txt").read_text().splitlines()
            if r.strip() and not r.startswith("#")
        ]
        with pytest.raises(CameraModelError, match=message.replace("(", r"\(").replace(")", r"\)").replace("*", r"\*")):
            OCamModel.parse("\n".join(mutate(rows)))

    def test_missing_file(self, tmp_path) -> None:
        with pytest.raises(CameraModelError, match="cannot be read"):
            OCamModel.from_file(tmp_path / "nope.txt")

    def test_nan_parameter_refused(self, ocam800: OCamModel) -> None:
        data = ocam800.model_dump()
        data["center_row"] = float("nan")
        with pytest.raises(ValueError, match="finite"):
            OCamModel(**data)


class TestValidArea:
    def test_ellipse_axes(self, ocam1600: OCamModel) -> None:
        cam = ocam1600.model_copy(update={"fov": 185.0})
        mask = cam.valid_area()
        assert mask.shape == (1600, 1600) and mask.dtype == np.uint8 and set(np.unique(mask)) <= {0, 255}
        row = int(round(cam.center_row))
        inside = np.flatnonzero(mask[row])
        assert (inside[-1] - inside[0] + 1) / 2 == pytest.approx(794.447, abs=1.0)


KB = KannalaBrandt(
    fx=300.0, fy=310.0, cx=401.0, cy=396.0, k=(0.1, -0.02, 0.003, -0.0004), width=800, height=800, fov=200.0
)


class TestKannalaBrandt:
    def test_agrees_with_opencv_fisheye(self) -> None:
        rng = np.random.default_rng(0)
        pts = rng.normal(size=(500, 3))
        pts[:, 2] = np.abs(pts[:, 2]) + 0.05
        uv, _ = KB.project(pts)
        k = np.array([[KB.fx, 0, KB.cx], [0, KB.fy, KB.cy], [0, 0, 1.0]])
        ref, _ = cv2.fisheye.projectPoints(pts.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, np.array(KB.k))
        np.testing.assert_allclose(uv, ref.reshape(-1, 2), atol=1e-6)

    def test_projects_beyond_ninety_degrees(self) -> None:
        wide = KB.model_copy(update={"fx": 200.0, "fy": 200.0})
        uv, valid = wide.project(_ray(95.0))
        assert valid[0] and uv[0, 0] > wide.cx

    def test_paper_polynomial_form(self) -> None:
        cam = KannalaBrandt.from_polynomial((300.0, 30.0, -6.0, 0.9, -0.12), cx=400, cy=400, width=800, height=800)
        theta = 0.8
        r = 300.0 * theta + 30.0 * theta**3 - 6.0 * theta**5 + 0.9 * theta**7 - 0.12 * theta**9
        uv, _ = cam.project(_ray(math.degrees(theta)))
        assert uv[0, 0] - 400 == pytest.approx(r, abs=1e-9)

    def test_equidistant_is_linear_in_angle(self) -> None:
        cam = Equidistant(fx=250.0, fy=250.0, cx=400.0, cy=400.0, width=800, height=800)
        uv, _ = cam.project(_ray(60.0))
        assert uv[0, 0] - 400 == pytest.approx(250.0 * math.radians(60.0))
        with pytest.raises(ValueError, match="no distortion"):
            Equidistant(fx=250.0, fy=250.0, cx=400.0, cy=400.0, k=(0.1, 0, 0, 0), width=800, height=800)

    def test_pinhole_rejects_rays_behind(self) -> None:
        cam = Pinhole(fx=500.0, fy=500.0, cx=320.0, cy=240.0, width=640, height=480)
        uv, valid = cam.project(np.array([[0.1, 0.1, 1.0], [0.1, 0.1, -1.0]]))
        np.testing.assert_allclose(uv[0], [370.0, 290.0])
        assert valid.tolist() == [True, False]


pixel = st.tuples(st.floats(0.0, 1.0), st.floats(0.0, 1.0))


@pytest.mark.parametrize(
    "camera",
    [
        pytest.param(lambda rig: rig.shared_model(), id="ocam"),
        pytest.param(lambda rig: KB, id="kannala-brandt"),
        pytest.param(
            lambda rig: Equidistant(fx=230.0, fy=230.0, cx=400.0, cy=400.0, width=800, height=800, fov=220.0),
            id="equidistant",
        ),
        pytest.param(lambda rig: Pinhole(fx=500.0, fy=480.0, cx=320.0, cy=240.0, width=640, height=480), id="pinhole"),
    ],
)
@settings(max_examples=60, deadline=None)
@given(p=pixel)
def test_project_unproject_round_trip(camera, rig, p) -> None:
    """project(unproject(uv)) == uv for pixels inside the valid area (OCam: the fov ellipse)."""
    cam = camera(rig)
    uv = np.array([[p[0] * (cam.width - 1), p[1] * (cam.height - 1)]])
    if isinstance(cam, OCamModel):
        tolerance = 0.05  # pol and invpol are separate fits; the spec measures ~0.003 px
        if cam.valid_area()[int(round(uv[0, 1])), int(round(uv[0, 0]))] == 0:
            return
        if not (
            tolerance <= uv[0, 0] <= cam.width - 1 - tolerance and tolerance <= uv[0, 1] <= cam.height - 1 - tolerance
        ):
            return  # on the image's edge the round trip's error can step outside it (measured: u = -0.001 at u = 0)
    else:
        tolerance = 1e-6
    back, valid = cam.project(cam.unproject(uv))
    if isinstance(cam, KannalaBrandt) and not valid[0]:
        return  # outside the lens's fov: no round trip is promised
    assert valid[0]
    np.testing.assert_allclose(back, uv, atol=tolerance)


class TestKbToOcamFit:
    @pytest.mark.parametrize(
        "kb", [KB, Equidistant(fx=230.0, fy=240.0, cx=400.0, cy=410.0, width=800, height=800, fov=220.0)]
    )
    def test_fit_reprojects_within_a_hundredth_of_a_pixel(self, kb: KannalaBrandt) -> None:
        fit = fit_ocam_from_kb(kb)
        assert fit.max_reprojection_error_px < 0.01
        rays = np.array([[0.3, -0.2, 0.9], [0.9, 0.1, -0.1]])
        np.testing.assert_allclose(fit.model.world2cam(rays), kb.project(rays)[0], atol=0.01)

    def test_low_degree_fit_reports_its_larger_error(self) -> None:
        assert fit_ocam_from_kb(KB, pol_degree=3).max_unproject_error_px > fit_ocam_from_kb(KB).max_unproject_error_px
