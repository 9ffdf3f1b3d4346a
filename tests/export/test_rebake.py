"""Re-baking for a new rig: equal to a fresh export, refuses what does not fit, needs no torch."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import numpy_helper
from small_configs import move_rig, small_configs

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
def test_rebaked_file_equals_a_fresh_export(arch: str, tmp_path: Path, small_exports) -> None:  # noqa: ANN001
    """On the reduced configurations: the same code path as full size, in a fraction of the time."""
    pytest.importorskip("torch")
    from fisheye_infer.export.exporter import export

    config, rig = small_configs()[arch]
    moved_rig = move_rig(rig)
    exported = small_exports(arch)
    rebaked = tmp_path / "rebaked.onnx"
    meta = rebake(exported.onnx, moved_rig, rebaked)
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
    assert meta.rig_hash == moved_rig.hash == fresh.meta.rig_hash and meta.model_id == fresh.meta.model_id
    assert read_meta(rebaked).model_dump(exclude={"parity"}) == fresh.meta.model_dump(exclude={"parity"})
    assert read_meta(rebaked).parity is None  # re-baking runs no PyTorch comparison; it claims none


def test_rebake_refuses_rigs_that_do_not_fit(bevdet_export, rig: Rig, tmp_path: Path) -> None:
    small = resized_rig(rig, 0.5)
    with pytest.raises(RigError, match="image is 400x400, model expects 800x800"):
        rebake(bevdet_export.onnx, small, tmp_path / "x.onnx")
    three = Rig.from_dict({**rig.model_dump(mode="json"), "cameras": rig.model_dump(mode="json")["cameras"][:3]})
    with pytest.raises(RigError, match="3 cameras"):
        rebake(bevdet_export.onnx, three, tmp_path / "x.onnx")
    data = rig.model_dump(mode="json")
    data["cameras"] = data["cameras"][::-1]
    with pytest.raises(RigError, match="camera order"):
        rebake(bevdet_export.onnx, Rig.from_dict(data), tmp_path / "x.onnx")
    with pytest.raises(ArtifactError, match="never overwrites its input"):
        rebake(bevdet_export.onnx, rig, bevdet_export.onnx)
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


def test_rebake_command_runs_without_torch(petr_export, moved_rig: Rig, tmp_path: Path) -> None:
    rig_file = moved_rig.save(tmp_path / "moved.yaml")
    out = tmp_path / "rebaked.onnx"
    result = subprocess.run(
        [sys.executable, "-c", BLOCK_TORCH, "rebake", str(petr_export.onnx), "--rig", str(rig_file), "--out", str(out)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert "geometry tables recomputed" in result.stdout
    assert read_meta(out).rig_hash == moved_rig.hash
