"""Every registered architecture, as timm tests its models: registering one signs it up.

For each name in ``list_models()``: build it, strictly load a synthetic checkpoint in the official
format, run a forward pass, and export it to a verified ONNX file whose metadata says what the
registry and the configuration say. Reduced configurations keep it to seconds (``small_configs``).
"""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
from small_configs import small_configs  # noqa: E402

from fisheye_infer.cameras.rig import default_rig
from fisheye_infer.errors import CheckpointError
from fisheye_infer.export.exporter import infer_architecture
from fisheye_infer.models import create_model, get_model_entry, list_models, load_model, make_checkpoint
from fisheye_infer.runtime.artifact import read_meta

REDUCED = small_configs()


def _setup(arch: str) -> tuple[object, object]:
    return REDUCED.get(arch, (None, default_rig()))


@pytest.fixture(scope="module", params=list_models())
def built(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Path, object, object]:
    arch = request.param
    config, rig = _setup(arch)
    ckpt = tmp_path_factory.mktemp(arch) / f"{arch}.pth"
    make_checkpoint(arch, seed=2, path=ckpt, config=config, rig=rig)
    return arch, ckpt, config, rig


def test_entry_describes_the_architecture(built) -> None:  # noqa: ANN001
    arch, _, config, rig = built
    entry = get_model_entry(arch)
    model = create_model(arch, config, rig)
    assert type(model) is entry.builder and type(model.config) is entry.config_cls
    assert entry.signature_keys and entry.score_semantics and entry.manifest.endswith(".json")
    pre = model.config.preprocess
    assert pre.cameras == tuple(rig.names) and pre.image_size == (
        rig.cameras[0].model.width,
        rig.cameras[0].model.height,
    )
    assert len(pre.classes) == model.config.num_classes and len(pre.mean) == len(pre.std) == 3


def test_strict_load_and_forward(built) -> None:  # noqa: ANN001
    arch, ckpt, config, rig = built
    state_dict = torch.load(ckpt, weights_only=True)["state_dict"]
    assert infer_architecture(state_dict, config) == arch
    model, report = load_model(arch, ckpt, config, rig)
    assert all(c.agrees for c in report.checks)
    w, h = model.config.preprocess.image_size
    images = torch.randint(
        0, 256, (1, model.config.num_cameras, h, w, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(0)
    )
    with torch.no_grad():
        out = model(images, torch.ones(1, model.config.num_cameras, dtype=torch.bool))
    k = model.config.num_boxes
    assert tuple(out["boxes"].shape) == (1, k, 7) and tuple(out["scores"].shape) == (1, k)
    assert torch.isfinite(out["boxes"]).all() and torch.isfinite(out["scores"]).all()
    dropped = dict(state_dict)
    dropped.pop(next(iter(model.state_dict())))
    with pytest.raises(CheckpointError, match="missing keys"):
        load_model(arch, {"state_dict": dropped}, config, rig)


@pytest.mark.slow  # a whole export: make test-fast leaves it out
def test_export_is_verified_and_described(built, small_exports) -> None:  # noqa: ANN001
    arch, _, config, rig = built
    result = small_exports(arch).result  # the same reduced configuration, rig and seed as ``built``
    assert result.parity.passed and result.path is not None
    meta = read_meta(result.path)
    model = create_model(arch, config, rig)
    pre = model.config.preprocess
    assert meta.architecture == arch and meta.score_semantics == get_model_entry(arch).score_semantics
    assert meta.classes == pre.classes and meta.cameras == pre.cameras and meta.image_size == pre.image_size
    assert (meta.normalisation.mean, meta.normalisation.std) == (
        pre.mean,
        pre.std,
    ) and meta.num_boxes == model.config.num_boxes
    assert meta.geometry == model.geometry_params() and set(meta.geometry_initializers) == set(model.geometry_tables())
