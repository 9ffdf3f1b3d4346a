"""The models shipped with the package: trained checkpoints with their config, rig and model card.

    from fisheye_infer.models.pretrained import COMPACT_BEVDET
    export(COMPACT_BEVDET.checkpoint, "model.onnx", config=COMPACT_BEVDET.config, rig=COMPACT_BEVDET.rig)

Each lives in a folder of its own (``model.pth``, ``config.py``, ``rig.json``, ``MODEL_CARD.md``,
and ``heldout_frame/``: one validation frame it never trained on, with its labels), so the files
are usable as they are by ``fisheye-infer export --ckpt/--config/--rig``.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

__all__ = ["Pretrained", "COMPACT_BEVDET"]


@dataclass(frozen=True)
class Pretrained:
    """A shipped model's folder and the files in it."""

    name: str
    folder: Path

    @property
    def checkpoint(self) -> Path:
        return self.folder / "model.pth"

    @property
    def config(self) -> Path:
        return self.folder / "config.py"

    @property
    def rig(self) -> Path:
        return self.folder / "rig.json"

    @property
    def card(self) -> Path:
        return self.folder / "MODEL_CARD.md"

    @property
    def heldout_frame(self) -> Path:
        """Folder with one image per camera and ``labels.json`` (the frame's ground-truth records)."""
        return self.folder / "heldout_frame"


#: The compact FisheyeBEVDet trained on randomised synthetic frames (``fisheye-infer train``).
COMPACT_BEVDET = Pretrained("fisheye-bevdet-compact", Path(__file__).resolve().parent / "fisheye_bevdet_compact")
