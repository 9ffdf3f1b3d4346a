"""The models shipped with the package: trained checkpoints with their config, rig and model card.

    from fisheye_infer.models.pretrained import COMPACT_BEVDET, pretrained
    export(COMPACT_BEVDET.checkpoint, "model.onnx", config=COMPACT_BEVDET.config, rig=COMPACT_BEVDET.rig)
    shipped = pretrained("fisheye-petr-compact")

Each lives in a folder of its own (``model.pth``, ``config.py``, ``rig.json``, ``MODEL_CARD.md``,
and ``heldout_frame/``: one validation frame it never trained on, with its labels), so the files
are usable as they are by ``fisheye-infer export --ckpt/--config/--rig``.

- ``COMPACT_BEVDET`` (``fisheye-bevdet-compact``): the compact FisheyeBEVDet trained on randomised synthetic
  frames (``fisheye-infer train``); boxes shown from score 0.15.
- ``COMPACT_PETR`` (``fisheye-petr-compact``): the compact FisheyePETR, trained on the same frames with the
  compact FisheyeBEVDet's image backbone frozen; boxes shown from score 0.4.
- ``PRETRAINED``: both, in that order.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

__all__ = ["Pretrained", "COMPACT_BEVDET", "COMPACT_PETR", "PRETRAINED", "pretrained"]


@dataclass(frozen=True)
class Pretrained:
    """A shipped model's folder and the files in it, and the score from which its boxes are shown.

    Attributes:
        name (str): The model's name (``fisheye-bevdet-compact``, ``fisheye-petr-compact``).
        folder (Path): Its folder in the installed package.
        score_threshold (float): Where the model's F1 (2 m, same class) peaks on held-out frames; scores of
            different models do not compare (a TransFusion heatmap peak, a PETR query's sigmoid), so each
            model has its own.

    Examples:
        ```python
        from fisheye_infer.export import export
        from fisheye_infer.models.pretrained import pretrained

        model = pretrained("fisheye-bevdet-compact")
        export(model.checkpoint, "model.onnx", config=model.config, rig=model.rig)
        ```
    """

    name: str
    folder: Path
    score_threshold: float

    @property
    def checkpoint(self) -> Path:
        """The weights, ``model.pth`` (mmengine format)."""
        return self.folder / "model.pth"

    @property
    def config(self) -> Path:
        """The official-format config file, ``config.py``."""
        return self.folder / "config.py"

    @property
    def rig(self) -> Path:
        """The rig file it was trained for, ``rig.json``."""
        return self.folder / "rig.json"

    @property
    def card(self) -> Path:
        """The model card, ``MODEL_CARD.md``: data, training, scores."""
        return self.folder / "MODEL_CARD.md"

    @property
    def heldout_frame(self) -> Path:
        """Folder with one image per camera and ``labels.json`` (the frame's ground-truth records)."""
        return self.folder / "heldout_frame"


_HERE = Path(__file__).resolve().parent
#: The compact FisheyeBEVDet trained on randomised synthetic frames (``fisheye-infer train``). Its F1 peaks at
#: 0.15 (recall 0.62, precision 0.82 on 100 held-out frames; 0.1 gives 0.69 and 0.67, 0.3 keeps 0.95
#: precision at 0.43 recall).
COMPACT_BEVDET = Pretrained("fisheye-bevdet-compact", _HERE / "fisheye_bevdet_compact", 0.15)
#: The compact FisheyePETR, trained on the same frames with the compact FisheyeBEVDet's image backbone frozen.
#: Its F1 peaks at 0.4 (recall 0.55, precision 0.70 on 200 held-out frames; 0.3 gives 0.61 and 0.61, 0.5
#: gives 0.50 and 0.76).
COMPACT_PETR = Pretrained("fisheye-petr-compact", _HERE / "fisheye_petr_compact", 0.4)
#: Every shipped model.
PRETRAINED = (COMPACT_BEVDET, COMPACT_PETR)


def pretrained(name: str) -> Pretrained:
    """The shipped model called ``name``.

    Args:
        name (str): ``fisheye-bevdet-compact`` or ``fisheye-petr-compact``.

    Returns:
        Pretrained: The model's folder and files.

    Raises:
        KeyError: No shipped model of that name (the shipped ones are listed).

    Examples:
        ```python
        from fisheye_infer.models.pretrained import pretrained

        shipped = pretrained("fisheye-petr-compact")
        shipped.checkpoint, shipped.config, shipped.rig, shipped.score_threshold
        ```
    """
    for model in PRETRAINED:
        if model.name == name:
            return model
    raise KeyError(f"no shipped model {name!r} (shipped: {', '.join(m.name for m in PRETRAINED)})")
