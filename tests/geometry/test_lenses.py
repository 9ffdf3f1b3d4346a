"""A lens per camera: every fisheye geometry samples each camera with its own calibration."""

from __future__ import annotations

import numpy as np
import pytest
from small_configs import own_lenses, small_configs

from fisheye_infer.cameras.rig import Rig, pinhole_rig
from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.grids import fisheye_lenses, stored_for_first_lens

torch = pytest.importorskip("torch")

from fisheye_infer.models import create_model  # noqa: E402

FISHEYE = ["fisheye-bevdet", "fisheye-petr", "fisheye-bevdet-cyl", "fisheye-petr-cyl", "fisheye-bevdet-persp",
           "fisheye-petr-persp"]  # fmt: skip


def _every_camera_with(rig: Rig, n: int) -> Rig:
    """``rig`` with camera ``n``'s lens on every camera."""
    data = rig.model_dump(mode="json")
    for cam in data["cameras"]:
        cam["model"] = data["cameras"][n]["model"]
    return Rig.from_dict(data)


def _per_camera(tables: dict, cameras: int) -> dict[str, np.ndarray]:
    """The sampling taps and the key mask of each camera, camera by camera."""
    names = [k for k in tables if k.startswith(("geom.warp.", "geom.rectify.")) or k == "geom.petr.key_mask"]
    return {k: np.asarray(tables[k]).reshape(cameras, -1) for k in names}


@pytest.mark.parametrize("arch", FISHEYE)
def test_each_camera_samples_with_its_own_lens(arch: str) -> None:
    """Camera n's taps (and key mask) on a rig of four lenses are those it has on a rig of four copies of its lens."""
    config, rig = small_configs()[arch]
    mine = own_lenses(rig)
    cameras = len(mine)
    tables = _per_camera(create_model(arch, config, mine).geometry_tables(), cameras)
    assert any(k.startswith(("geom.warp.", "geom.rectify.")) for k in tables)
    for n in range(cameras):
        alone = _per_camera(create_model(arch, config, _every_camera_with(mine, n)).geometry_tables(), cameras)
        for name, table in tables.items():
            np.testing.assert_array_equal(table[n], alone[name][n], err_msg=f"{name}, camera {n}")
    weight = tables[next(k for k in tables if k.endswith(".weight"))]
    assert all(not np.array_equal(weight[n], weight[0]) for n in range(1, cameras))


def test_a_checkpoint_table_replaces_the_cameras_of_the_first_lens() -> None:
    tables = np.stack([np.zeros((2, 3)), np.ones((2, 3)), np.zeros((2, 3))]).astype(np.float32)
    stored = np.full((2, 3), 7.0, np.float32)
    np.testing.assert_array_equal(stored_for_first_lens(tables, stored)[:, 0, 0], [7.0, 1.0, 7.0])


def test_a_camera_without_an_ocam_model_is_named() -> None:
    with pytest.raises(ConfigError, match="camera 'nu_rgb_camera_front': a pinhole model; .* OCam"):
        fisheye_lenses(pinhole_rig())
