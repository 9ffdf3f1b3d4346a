"""Re-baking for a new rig: equal to a fresh export, refuses what does not fit, needs no torch."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import pytest
from onnx import numpy_helper
from small_configs import move_rig, own_lenses, small_configs

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ArtifactError, RigError
from fisheye_infer.export.rebake import rebake
from fisheye_infer.runtime.artifact import read_meta
from fisheye_infer.scenes.render import resized_rig

ROOT = Path(__file__).resolve().parents[2]


def _geometry(path: Path) -> dict[str, np.ndarray]:
    return {
        i.name: numpy_helper.to_array(i) for i in onnx.load(str(path)).graph.initializer if i.name.startswith("geom.")
    }


def _nodes(graph: onnx.GraphProto) -> list[tuple]:
    return [
        (n.op_type, n.domain, tuple(n.input), tuple(n.output), tuple(a.SerializeToString() for a in n.attribute))
        for n in graph.node
    ]


def _initializers(graph: onnx.GraphProto) -> dict[str, np.ndarray]:
    return {i.name: numpy_helper.to_array(i) for i in graph.initializer}


@pytest.mark.parametrize("arch", ["fisheye-bevdet", "fisheye-petr"])
def test_rebaked_file_equals_a_fresh_export(arch: str, tmp_path: Path, small_exports: Callable[[str], Any]) -> None:
    """On the reduced configurations: the same code path as full size, in a fraction of the time. The fresh
    export's self-check holds it to the PyTorch model of the new rig: every camera moved and with a lens of its
    own (a file exported for one shared lens re-baked for four calibrations)."""
    pytest.importorskip("torch")
    from fisheye_infer.export.exporter import export

    config, rig = small_configs()[arch]
    moved_rig = own_lenses(move_rig(rig))
    exported = small_exports(arch)
    rebaked = tmp_path / "rebaked.onnx"
    meta = rebake(exported.onnx, moved_rig, rebaked, mode="tables")
    quiet = {"frames": 1, "threads": (1,), "progress": lambda _: None}  # as the shared export's
    fresh = export(exported.ckpt, tmp_path / "fresh.onnx", config=config, rig=moved_rig, geometry="rig", **quiet)
    mine, theirs = onnx.load(str(rebaked)).graph, onnx.load(str(fresh.path)).graph
    assert _nodes(mine) == _nodes(theirs)  # the same graph ...
    a, b = _initializers(mine), _initializers(theirs)
    assert sorted(a) == sorted(b)
    for name in a:  # ... holding the same weights and the same geometry tables, bit for bit
        assert a[name].dtype == b[name].dtype, name
        np.testing.assert_array_equal(a[name], b[name], err_msg=name)
    assert any(not np.array_equal(a[n], v) for n, v in _geometry(exported.onnx).items())  # the rig really changed
    weight = a["geom.warp.weight"].reshape(len(rig), -1)  # each camera reads its own lens's taps
    assert all(not np.array_equal(weight[n], weight[0]) for n in range(1, len(rig)))
    assert meta.rig_hash == moved_rig.hash == fresh.meta.rig_hash and meta.model_id == fresh.meta.model_id
    assert read_meta(rebaked).model_dump(exclude={"parity"}) == fresh.meta.model_dump(exclude={"parity"})
    assert read_meta(rebaked).parity is None  # re-baking runs no PyTorch comparison; it claims none


def test_rebake_refuses_rigs_that_do_not_fit(bevdet_export, rig: Rig, tmp_path: Path) -> None:
    small = resized_rig(rig, 0.5)
    with pytest.raises(RigError, match="image is 400x400, model expects 800x800"):
        rebake(bevdet_export.onnx, small, tmp_path / "x.onnx", mode="tables")
    three = Rig.from_dict({**rig.model_dump(mode="json"), "cameras": rig.model_dump(mode="json")["cameras"][:3]})
    with pytest.raises(RigError, match="3 cameras"):
        rebake(bevdet_export.onnx, three, tmp_path / "x.onnx", mode="tables")
    with pytest.raises(RigError, match="camera 'fisheye_camera_rear': no robot camera looks within 45°"):
        rebake(bevdet_export.onnx, three, tmp_path / "x.onnx")  # virtual cameras: none stands in the rear one
    data = rig.model_dump(mode="json")
    data["cameras"] = data["cameras"][::-1]
    with pytest.raises(RigError, match="camera order"):
        rebake(bevdet_export.onnx, Rig.from_dict(data), tmp_path / "x.onnx", mode="tables")
    with pytest.raises(ArtifactError, match="never overwrites its input"):
        rebake(bevdet_export.onnx, rig, bevdet_export.onnx)
    assert not (tmp_path / "x.onnx").exists()


def test_rebake_refuses_a_table_of_another_shape(small_exports: Callable[[str], Any], tmp_path: Path) -> None:
    """A file whose warp holds one set of taps for all cameras (its first camera's, as files of another
    version of the exporter did) is not given four: its graph reads them in its own layout."""
    exported = small_exports("fisheye-bevdet")
    proto = onnx.load(str(exported.onnx))
    for init in proto.graph.initializer:
        if init.name in ("geom.warp.index", "geom.warp.weight"):
            table = numpy_helper.to_array(init)
            init.CopyFrom(numpy_helper.from_array(table[: len(table) // 4].copy(), init.name))
    older = tmp_path / "older.onnx"
    onnx.save(proto, str(older))
    _, rig = small_configs()["fisheye-bevdet"]
    with pytest.raises(ArtifactError, match=r"geom.warp.\w+ is \(\d+.*export the checkpoint again"):
        rebake(older, own_lenses(rig), tmp_path / "x.onnx", mode="tables")
    assert not (tmp_path / "x.onnx").exists()


BLOCK_TORCH = (
    "import importlib.abc, sys\n"
    "class Block(importlib.abc.MetaPathFinder):\n"
    "    def find_spec(self, name, path=None, target=None):\n"
    "        if name.split('.')[0] == 'torch': raise ImportError('torch is not installed')\n"
    "sys.meta_path.insert(0, Block())\n"
    "from fisheye_infer.cli import main\n"
    "sys.exit(main(sys.argv[1:]))\n"
)


@pytest.mark.parametrize("tables", [True, False], ids=["tables", "virtual"])
def test_rebake_command_runs_without_torch(petr_export, moved_rig: Rig, tmp_path: Path, tables: bool) -> None:
    rig_file = moved_rig.save(tmp_path / "moved.yaml")
    out = tmp_path / "rebaked.onnx"
    argv = ["rebake", str(petr_export.onnx), "--rig", str(rig_file), "--out", str(out), *(["--tables"] * tables)]
    result = subprocess.run([sys.executable, "-c", BLOCK_TORCH, *argv], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert ("geometry tables recomputed" if tables else "virtual cameras") in result.stdout
    assert read_meta(out).rig_hash == moved_rig.hash
