"""FisheyePETR's key mask and embedding through re-baking: a file's own tables (a checkpoint's) are the trained
ones; virtual cameras raise that mask for unseen pixels and never lose or accumulate it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import numpy_helper

from fisheye_infer.cameras.camera_models import Equidistant
from fisheye_infer.cameras.rig import Rig
from fisheye_infer.export.graph import (
    REBAKE_WEIGHTS_KEY,
    decode_arrays,
    get_metadata,
    replace_initializers,
    save_model,
    set_metadata,
)
from fisheye_infer.export.rebake import rebake
from fisheye_infer.geometry.kinds import geometry_from_rig
from fisheye_infer.geometry.petr import PETRGeometry, key_position_embedding, remasked_key_embedding
from fisheye_infer.geometry.tables import PETR_KEY_MASK, PETR_KEY_POS, key_tables
from fisheye_infer.geometry.virtual import virtual_front
from fisheye_infer.runtime.artifact import read_meta

KEYS = (PETR_KEY_POS, PETR_KEY_MASK)


def _keys(path: Path) -> dict[str, np.ndarray]:
    return {i.name: numpy_helper.to_array(i) for i in onnx.load(str(path)).graph.initializer if i.name in KEYS}


def _geometry_and_weights(path: Path) -> tuple[PETRGeometry, dict[str, np.ndarray]]:
    meta = read_meta(path)
    geometry = geometry_from_rig(meta.training_rig, meta.geometry)
    assert isinstance(geometry, PETRGeometry)
    return geometry, decode_arrays(get_metadata(onnx.load(str(path)))[REBAKE_WEIGHTS_KEY])


@pytest.fixture(scope="module")
def checkpoint_file(small_exports, tmp_path_factory: pytest.TempPathFactory) -> Path:
    """The small FisheyePETR with a key mask of its own (its lenses' plus each camera's first row of keys), the key
    embedding to match, and ``geometry_source: checkpoint``: what an export from a checkpoint's stored tables is."""
    exported = small_exports("fisheye-petr")
    geometry, weights = _geometry_and_weights(exported.onnx)
    mask = geometry.key_mask().copy()
    mask[:, 0, :] = True
    proto = onnx.load(str(exported.onnx))
    replace_initializers(proto, key_tables(geometry.with_key_mask(mask).key_pos(weights), mask))
    meta = read_meta(exported.onnx).model_copy(update={"geometry_source": "checkpoint"})
    set_metadata(proto, meta)
    return save_model(proto, tmp_path_factory.mktemp("petr_keys") / "checkpoint.onnx")


def _narrow(rig: Rig) -> Rig:
    side = rig.cameras[0].model.width
    lens = Equidistant(
        width=side, height=side, fx=side / 4, fy=side / 4, cx=(side - 1) / 2, cy=(side - 1) / 2, fov=150.0
    )
    return rig.model_copy(update={"cameras": tuple(c.model_copy(update={"model": lens}) for c in rig.cameras)})


def test_the_mask_part_of_the_embedding_moves_alone() -> None:
    """Moving an embedding from one mask to another equals computing it with the other mask; equal masks keep it."""
    rng = np.random.default_rng(0)
    n, c, h, w, hidden, feats = 2, 6, 5, 7, 8, 4
    weights = {
        "position_encoder.0.weight": rng.normal(size=(hidden, c, 1, 1)),
        "position_encoder.0.bias": rng.normal(size=hidden),
        "position_encoder.2.weight": rng.normal(size=(hidden, hidden, 1, 1)),
        "position_encoder.2.bias": rng.normal(size=hidden),
        "adapt_pos3d.0.weight": rng.normal(size=(hidden, 3 * feats, 1, 1)),
        "adapt_pos3d.0.bias": rng.normal(size=hidden),
        "adapt_pos3d.2.weight": rng.normal(size=(hidden, hidden, 1, 1)),
        "adapt_pos3d.2.bias": rng.normal(size=hidden),
    }

    class Sine:
        num_feats, temperature = feats, 10000.0

    coords = rng.normal(size=(n, c, h, w))
    first, second = rng.random((n, h, w)) < 0.3, rng.random((n, h, w)) < 0.5
    embedded = key_position_embedding(coords, first, weights, Sine())
    moved = remasked_key_embedding(embedded, first, second, weights, Sine())
    np.testing.assert_allclose(moved, key_position_embedding(coords, second, weights, Sine()), atol=1e-5)
    np.testing.assert_array_equal(remasked_key_embedding(embedded, first, first.copy(), weights, Sine()), embedded)


def test_a_checkpoints_keys_survive_virtual_cameras_on_its_own_rig(checkpoint_file: Path, tmp_path: Path) -> None:
    meta = read_meta(checkpoint_file)
    for mode in ("virtual", "tables"):
        rebake(checkpoint_file, meta.rig, tmp_path / f"{mode}.onnx", mode=mode)
        got, held = _keys(tmp_path / f"{mode}.onnx"), _keys(checkpoint_file)
        for name in KEYS:
            np.testing.assert_array_equal(got[name], held[name], err_msg=f"{mode}: {name}")
    assert read_meta(tmp_path / "tables.onnx").geometry_source == "checkpoint"


def test_unseen_pixels_raise_the_trained_mask_and_a_second_rebake_starts_from_it(
    checkpoint_file: Path, tmp_path: Path
) -> None:
    meta = read_meta(checkpoint_file)
    geometry, weights = _geometry_and_weights(checkpoint_file)
    held = _keys(checkpoint_file)
    trained = held[PETR_KEY_MASK].reshape(geometry.unvalid_area.shape)
    robot = _narrow(meta.rig)
    rebake(checkpoint_file, robot, tmp_path / "narrow.onnx")
    front = virtual_front(meta.rig, robot, [c.name for c in meta.rig.cameras])
    unseen = np.stack([view.unseen for view in front.views])
    expected = geometry.with_key_mask(trained).with_unseen(unseen).key_mask()
    got = _keys(tmp_path / "narrow.onnx")
    np.testing.assert_array_equal(got[PETR_KEY_MASK].reshape(expected.shape), expected)
    assert expected.sum() > trained.sum() and (expected >= trained).all()
    moved = remasked_key_embedding(held[PETR_KEY_POS], trained, expected, weights, geometry.params)
    np.testing.assert_array_equal(got[PETR_KEY_POS], moved)

    rebake(tmp_path / "narrow.onnx", meta.rig, tmp_path / "again.onnx", mode="virtual")
    rebake(tmp_path / "narrow.onnx", meta.rig, tmp_path / "back.onnx", mode="tables")
    for name in ("again", "back"):
        got = _keys(tmp_path / f"{name}.onnx")
        np.testing.assert_array_equal(got[PETR_KEY_MASK], held[PETR_KEY_MASK], err_msg=name)
        np.testing.assert_allclose(got[PETR_KEY_POS], held[PETR_KEY_POS], atol=1e-5, err_msg=name)
    assert read_meta(tmp_path / "back.onnx").virtual_cameras is None
