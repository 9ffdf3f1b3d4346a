"""Each shipped model: its files, its export, and that it detects on frames it never saw.

The frames are the validation stream's 300-331 (the training command never draws from that
stream; the model cards' figures use frames 0-199 and the bundled frame is 210). On these 32
frames (ONNX Runtime) the compact FisheyeBEVDet scores Car AP@2m 0.82 and mAP 0.55 within 30 m, and
the compact FisheyePETR 0.69 and 0.35. The bars (``BARS``) sit well below, so that another CPU's
last-bit differences can never fail them while a broken export, decoding or checkpoint (AP near 0)
always does, and so do the FisheyeBEVDet before its fine-tuning (0.63 and 0.36) and the FisheyePETR
of 300 queries its recipe starts from (0.10 and 0.22).
"""

from __future__ import annotations

from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from fisheye_infer.cameras.rig import Rig  # noqa: E402
from fisheye_infer.eval.dataset import Fisheye3DOD  # noqa: E402
from fisheye_infer.eval.evaluate import detect_dataset, evaluate_results  # noqa: E402
from fisheye_infer.models.pretrained import COMPACT_BEVDET, COMPACT_PETR, PRETRAINED, Pretrained  # noqa: E402
from fisheye_infer.runtime.detector import Detector  # noqa: E402
from fisheye_infer.scenes.streams import SyntheticFrames, write_split  # noqa: E402

FIRST, COUNT = 300, 32
#: Per shipped model: its architecture, and the bars of this test (Car AP@2m and mAP within 30 m; the model
#: cards' 200-frame figures are higher).
ARCH = {COMPACT_BEVDET.name: "fisheye-bevdet", COMPACT_PETR.name: "fisheye-petr"}
BARS = {COMPACT_BEVDET.name: (0.65, 0.4), COMPACT_PETR.name: (0.45, 0.25)}


@pytest.fixture(scope="session", params=PRETRAINED, ids=lambda m: m.name)
def shipped(request: pytest.FixtureRequest) -> Pretrained:
    return request.param


@pytest.fixture(scope="session")
def shipped_export(shipped: Pretrained, shipped_exports) -> Path:
    exported = shipped_exports(shipped.name)
    assert exported.result.parity.passed  # type: ignore[attr-defined]
    return exported.onnx


@pytest.fixture(scope="session")
def heldout(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Frames 300-331 of the validation stream through the shipped rig (every shipped model's)."""
    assert len({Rig.load(m.rig).hash for m in PRETRAINED}) == 1
    root = tmp_path_factory.mktemp("heldout")
    write_split(SyntheticFrames(Rig.load(COMPACT_BEVDET.rig), "val"), root, range(FIRST, FIRST + COUNT))
    return root


def test_the_shipped_files_are_complete_and_small(shipped: Pretrained) -> None:
    from fisheye_infer.models import get_model_entry, load_checkpoint

    assert shipped.checkpoint.stat().st_size <= 25e6
    _, meta = load_checkpoint(shipped.checkpoint)
    assert meta["arch"] == ARCH[shipped.name] and meta["synthetic"] is False
    assert meta["step"] == meta["train_options"]["steps"]
    config = get_model_entry(meta["arch"]).config_cls.from_mmdet3d_config(shipped.config)
    assert Rig.load(shipped.rig).hash == meta["rig_hash"] and config.to_dict() == meta["config"]
    card = shipped.card.read_text()
    assert "fisheye-infer train" in card and "benchmarks/model_card.py" in card
    assert {p.name for p in shipped.heldout_frame.iterdir()} >= {"labels.json", "fisheye_camera_front.png"}


def test_it_detects_objects_in_frames_it_never_saw(shipped: Pretrained, shipped_export: Path, heldout: Path) -> None:
    gt, pred = detect_dataset(Detector(shipped_export, threads=1), Fisheye3DOD(heldout, "val"), progress=False)
    near = evaluate_results(gt, pred).distance["0-30 m"]
    car_bar, map_bar = BARS[shipped.name]
    assert near.classes["Car"].ap_by_threshold["2.0"] >= car_bar, near.classes["Car"]
    assert near.mAP >= map_bar, near


def test_onnx_and_pytorch_give_the_same_metric(shipped: Pretrained, shipped_export: Path, heldout: Path) -> None:
    from fisheye_infer.export.exporter import open_checkpoint
    from fisheye_infer.export.torch_detector import TorchDetector

    data = Fisheye3DOD(heldout, "val", limit=8)
    model = open_checkpoint(shipped.checkpoint, config=shipped.config, rig=shipped.rig).model
    reports = [
        evaluate_results(*detect_dataset(detector, data, progress=False))
        for detector in (Detector(shipped_export, threads=1), TorchDetector(model, shipped_export))
    ]
    for label in ("0-30 m", "0-48 m"):
        onnx_side, torch_side = (r.distance[label] for r in reports)
        assert abs(onnx_side.FDS - torch_side.FDS) <= 1e-3 and abs(onnx_side.mAP - torch_side.mAP) <= 1e-3
    assert reports[0].main.num_pred > 0
