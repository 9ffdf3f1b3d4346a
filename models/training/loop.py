"""The training loop: seeded frames, AdamW with the official schedule, checkpoints and resumption.

The optimiser is the official one (AdamW, weight decay 0.01, gradient norm clipped at 35; a
linear warm-up from 1/3 of the rate over the first 500 steps, then cosine annealing to 2e-4 of
it). Three parts of the official recipe are left out: the momentum cycle, dropout (0.1 in the
official decoders; the plain-PyTorch decoders have none) and the ImageNet-pretrained ResNet-18
(``torchvision://resnet18``, not available offline; the backbone starts from seeded fan-in
weights, or from another run's image backbone with ``init_backbone``, and the classifiers from
the official prior biases). What each architecture minimises is its objective's
(``objectives.py``): FisheyeBEVDet's official losses plus the depth loss of ``depth.py`` (weight
``depth_weight``, 3 as BEVDepth; 0 leaves the official losses alone), which stands in for what
the pretrained backbone would bring; FisheyePETR's official losses of every decoder layer.

Step ``s`` trains on frames ``s*B .. s*B+B-1`` of the training split and the learning rate is a
function of the step, so a run is a pure function of its options: resuming from a checkpoint
continues with exactly the frames and rates the uninterrupted run would have used (the options and the
schedule are ``options.py``'s, the step batches ``batches.py``'s).

A run folder holds::

    config.py        the model configuration as an mmdet3d-style config (for ``fisheye-infer export --config``)
    rig.json         the rig the model was trained for (for ``--rig``)
    model.pth        official-format checkpoint {'state_dict', 'meta'} of the latest step
    checkpoint.pth   the same plus the optimiser state, for ``--resume``
    log.jsonl        one line per step: losses, learning rate, seconds; validation lines at checkpoints
"""

from __future__ import annotations

import dataclasses
import json
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import torch

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import CheckpointError, ConfigError
from fisheye_infer.geometry.lss import LSSGeometry
from fisheye_infer.geometry.petr import PETRGeometry
from fisheye_infer.scenes.streams import SyntheticFrames
from fisheye_infer.tools.files import pending_file

from ..fisheye_bevdet import FisheyeBEVDet
from ..fisheye_petr import FisheyePETR
from ..view_transform import FisheyeLSS, RectifiedLSS
from .batches import Batch, StepBatches, step_loader
from .config_file import write_config
from .lens_jitter import LensGeometry, LensJitter
from .objectives import objective_for
from .options import TrainOptions, lr_factor, training_device
from .qat import FakeQuant

__all__ = ["Trainer", "TRAINABLE", "arch_of", "read_config_file", "saved_options"]

#: What ``init_backbone`` loads: the image backbone and its neck, the same modules in every architecture.
BACKBONE_PREFIXES = ("img_backbone.", "img_neck.")
#: A query-based head's learned reference points, one row per query: what ``--init`` may grow.
QUERY_TABLE = "pts_bbox_head.reference_points.weight"
#: The architectures ``Trainer`` trains (each has an objective in ``objectives.py`` and a compact configuration
#: in ``compact.py``): the paper's two detectors and the baselines of its Table 2.
TRAINABLE = (
    "fisheye-bevdet",
    "fisheye-petr",
    "pinhole-bevdet",
    "fisheye-bevdet-persp",
    "fisheye-bevdet-cyl",
    "pinhole-petr",
    "fisheye-petr-persp",
    "fisheye-petr-cyl",
)


def arch_of(config: Any) -> str:
    """The trainable architecture whose configuration class ``config`` is."""
    from fisheye_infer.models import get_model_entry

    for name in TRAINABLE:
        if type(config) is get_model_entry(name).config_cls:
            return name
    raise ConfigError(f"no trainable architecture takes a {type(config).__name__} (trainable: {', '.join(TRAINABLE)})")


def read_config_file(path: str | Path) -> Any:
    """The configuration of an mmdet3d-style file of a trainable architecture: the one whose reader takes it."""
    from fisheye_infer.models import get_model_entry

    read, refusals = [], []
    for name in TRAINABLE:
        try:
            read.append(get_model_entry(name).config_cls.from_mmdet3d_config(path))
        except ConfigError as exc:
            refusals.append(f"{name}: {exc}")
    if len(read) == 1:
        return read[0]
    if not read:
        raise ConfigError(f"{path} is no configuration of a trainable architecture:\n  " + "\n  ".join(refusals))
    raise ConfigError(f"{path} reads as several architectures ({', '.join(arch_of(c) for c in read)})")


def saved_options(folder: Path) -> dict[str, Any]:
    """The options the run in ``folder`` was started with (its ``checkpoint.pth``), so that ``--resume``
    need repeat none of them; ``{}`` when the folder has no checkpoint yet."""
    path = folder / "checkpoint.pth"
    if not path.is_file():
        return {}
    # memory-mapped: only the metadata is read here; ``Trainer.resume`` loads the weights
    return _saved_options(torch.load(path, map_location="cpu", weights_only=True, mmap=True).get("meta", {}))


def _saved_options(meta: dict[str, Any]) -> dict[str, Any]:
    # runs made before fine-tuning, int8 simulation, backbone initialisation and lens jitter existed lack those fields
    saved = {
        "init": "",
        "qat": 0.0,
        "init_backbone": "",
        "freeze_backbone": False,
        "lens_jitter": 0.0,
        **meta.get("train_options", {}),
    }
    return {field.name: saved[field.name] for field in dataclasses.fields(TrainOptions) if field.name in saved}


def _atomic_save(obj: Any, path: Path) -> None:
    """A checkpoint appears whole or not at all: a run killed mid-save leaves the previous one."""
    with pending_file(path) as pending:
        torch.save(obj, pending.path)
        pending.commit()


def lens_jitter(model: torch.nn.Module, arch: str, rig: Rig, options: TrainOptions) -> LensJitter:
    """The run's lens-centre jitter; refused, naming the option, for a model (of ``arch``) whose geometry it
    does not move."""
    geometry = _lens_geometry(model)
    if geometry is None:
        raise ConfigError(
            "--lens-jitter: moves the lenses of fisheye-bevdet (its warp tables and depth masks) and fisheye-petr "
            f"(its warp tables and key mask); {arch} trains on its rig's lenses"
        )
    return LensJitter(geometry, rig, options.lens_jitter, options.seed)


def _lens_geometry(model: torch.nn.Module) -> LensGeometry | None:
    """The geometry a step's moved lenses replace: FisheyeBEVDet's spherical lift or FisheyePETR's spherical keys
    (None for the rectified and pinhole baselines, which sample their lenses through other tables)."""
    transform = getattr(model, "view_transform", None)
    if (
        isinstance(model, FisheyeBEVDet)
        and isinstance(transform, FisheyeLSS)
        and not isinstance(transform, RectifiedLSS)
        and isinstance(transform.geometry, LSSGeometry)
    ):
        return transform.geometry
    geometry = getattr(getattr(model, "pts_bbox_head", None), "geometry", None)
    return geometry if isinstance(model, FisheyePETR) and isinstance(geometry, PETRGeometry) else None


class Trainer:
    """Trains a model of ``config`` (the configuration of one of ``TRAINABLE``) for ``rig`` in the run folder
    ``out``.

    Trainer(compact_bevdet_config(), compact_rig(), "runs/compact", TrainOptions()).run()
    """

    def __init__(
        self,
        config: Any,
        rig: Rig,
        out: str | Path,
        options: TrainOptions = TrainOptions(),  # noqa: B008
        device: str = "cpu",
        workers: int = 0,
    ) -> None:  # noqa: B008 (frozen dataclasses)
        """``device``: where the model trains (``cpu``, ``cuda``, ``cuda:1``); ``workers``: processes
        that render the next steps' frames while this one trains (0: rendered in the loop). Neither
        changes what a step trains on."""
        from fisheye_infer.models import create_model, get_model_entry

        if workers < 0:
            raise ConfigError(f"--workers: expected 0 or more, got {workers}")
        self.arch = arch_of(config)
        self.config, self.rig, self.out, self.options = config, rig, Path(out), options
        self.device, self.workers = training_device(device), workers
        rig.require(rig.names, (config.image.width, config.image.height))
        torch.manual_seed(options.seed)
        self.model = create_model(self.arch, config, rig)
        self.objective = objective_for(self.model, options)
        self.objective.init(options.seed)
        labelled = self.objective.bev_range
        self.train_frames = SyntheticFrames(rig, "train", options.seed, bev_range=labelled)
        self.val_frames = SyntheticFrames(rig, "val", options.seed, bev_range=labelled)
        jitter = lens_jitter(self.model, self.arch, rig, options) if options.lens_jitter else None
        self.train_batches = StepBatches(self.train_frames, self.objective.depth_targets, options.batch_size, jitter)
        self.val_batches = StepBatches(self.val_frames, self.objective.depth_targets, 1)
        self.fake_quant = FakeQuant(self.model, get_model_entry(self.arch).int8_float) if options.qat else None
        if options.freeze_backbone:
            for name, param in self.model.named_parameters():
                param.requires_grad_(not name.startswith(BACKBONE_PREFIXES))
        self.model.to(self.device)
        trained = [p for p in self.model.parameters() if p.requires_grad]
        self.optimizer = torch.optim.AdamW(trained, lr=options.lr, weight_decay=options.weight_decay)
        self.step = 0

    # -- checkpoints ------------------------------------------------------------------------

    def _meta(self) -> dict[str, Any]:
        return {
            "arch": self.arch,
            "synthetic": False,
            "step": self.step,
            "config": self.config.to_dict(),
            "train_options": dataclasses.asdict(self.options),
            "rig": self.rig.name,
            "rig_hash": self.rig.hash,
        }

    def save(self) -> Path:
        """Write ``model.pth`` (official format) and ``checkpoint.pth`` (plus optimiser state) for the current step."""
        self.objective.settle()
        state = {k: v.detach().cpu().contiguous() for k, v in self.model.official_state_dict().items()}
        meta = self._meta()
        fake_quant = self.fake_quant.state() if self.fake_quant is not None else {}
        _atomic_save(
            {"state_dict": state, "meta": meta, "optimizer": self.optimizer.state_dict(), "fake_quant": fake_quant},
            self.out / "checkpoint.pth",
        )
        _atomic_save({"state_dict": state, "meta": meta}, self.out / "model.pth")
        return self.out / "model.pth"

    def resume(self) -> int:
        """Load ``checkpoint.pth`` of this run folder; refuse one made with other options or another configuration."""
        from fisheye_infer.models import load_official_state_dict

        path = self.out / "checkpoint.pth"
        if not path.is_file():
            raise CheckpointError(f"--resume: {path} does not exist (start the run without --resume)")
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        meta = ckpt.get("meta", {})
        self._check_origin(meta, f"--resume: {path}", recorded=True)
        saved = _saved_options(meta)
        mine = dataclasses.asdict(self.options)
        starts = ("init", "init_backbone")  # where the run's weights started; checkpoint.pth holds them now
        differ = [
            f"--{k.replace('_', '-')}: saved {saved.get(k)!r}, given {v!r}"
            for k, v in mine.items()
            if k not in ("steps", *starts) and saved.get(k) != v
        ]
        if differ:
            raise CheckpointError(f"--resume: {path} was made with other options ({'; '.join(differ)})")
        self.options = dataclasses.replace(self.options, **{k: saved[k] for k in starts})
        load_official_state_dict(self.model, ckpt["state_dict"], geometry="rig", context=str(path))
        self.optimizer.load_state_dict(ckpt["optimizer"])
        if self.fake_quant is not None:
            self.fake_quant.load_state(ckpt.get("fake_quant", {}), self.device)
        self.step = int(meta["step"])
        if self.options.steps < self.step:
            raise ConfigError(f"--steps {self.options.steps}: the run in {self.out} is already at step {self.step}")
        self._trim_log()
        return self.step

    def _trim_log(self) -> None:
        """Drop the log lines of steps after the checkpoint (a run killed between checkpoints logged them), so
        that the resumed run's lines follow on without repeating a step."""
        log = self.out / "log.jsonl"
        if log.is_file():
            lines = log.read_text().splitlines(keepends=True)
            log.write_text("".join(line for line in lines if json.loads(line)["step"] <= self.step))

    def load_init(self) -> None:
        """Start from the weights of ``options.init``; refuse a checkpoint of another configuration or rig."""
        from fisheye_infer.models import load_checkpoint, load_official_state_dict

        path = Path(self.options.init)
        if not path.is_file():
            raise CheckpointError(f"--init: {path} does not exist")
        state_dict, meta = self._grown_queries(*load_checkpoint(path))
        self._check_origin(meta, f"--init: {path}", recorded=False)
        load_official_state_dict(self.model, state_dict, geometry="rig", context=f"--init {path}")

    def _grown_queries(
        self, state_dict: dict[str, torch.Tensor], meta: dict[str, Any]
    ) -> tuple[dict[str, torch.Tensor], dict[str, Any]]:
        """A checkpoint of this configuration but for fewer queries (``num_query``) becomes one of this
        configuration: its reference points are the first of this run's, the others keep their seeded
        ones, so a trained decoder takes more queries without starting over. Any other checkpoint is
        returned as it is, for ``_check_origin`` to judge."""
        mine, theirs = self.config.to_dict(), meta.get("config")
        wanted = mine.get("head", {}).get("num_query")
        if wanted is None or not isinstance(theirs, dict) or not isinstance(theirs.get("head"), dict):
            return state_dict, meta
        have = theirs["head"].get("num_query")
        grown = {**theirs, "head": {**theirs["head"], "num_query": wanted}}
        if not isinstance(have, int) or have >= wanted or grown != mine:
            return state_dict, meta
        table = self.model.state_dict()[QUERY_TABLE].clone()
        table[:have] = state_dict[QUERY_TABLE]
        return {**state_dict, QUERY_TABLE: table}, {**meta, "config": mine}

    def load_backbone(self) -> None:
        """Start the image backbone and neck (``img_backbone.*``, ``img_neck.*``) from ``options.init_backbone``,
        a checkpoint of any architecture with the same backbone section; the rest keeps its seeded weights."""
        from fisheye_infer.models import load_checkpoint

        path = Path(self.options.init_backbone)
        if not path.is_file():
            raise CheckpointError(f"--init-backbone: {path} does not exist")
        state_dict, _meta = load_checkpoint(path)
        mine = {k: v for k, v in self.model.state_dict().items() if k.startswith(BACKBONE_PREFIXES)}
        theirs = {k: v for k, v in state_dict.items() if k.startswith(BACKBONE_PREFIXES)}
        missing = sorted(set(mine) - set(theirs))
        if missing:
            raise CheckpointError(f"--init-backbone: {path} has no {missing[0]} ({len(missing)} backbone keys missing)")
        for k, v in mine.items():
            if tuple(theirs[k].shape) != tuple(v.shape):
                theirs_shape, mine_shape = tuple(theirs[k].shape), tuple(v.shape)
                raise CheckpointError(
                    f"--init-backbone: {path}: {k} is {theirs_shape}, this configuration's is {mine_shape}"
                )
        self.model.load_state_dict(theirs, strict=False)

    def _check_origin(self, meta: dict[str, Any], what: str, recorded: bool) -> None:
        """Refuse a checkpoint whose ``meta`` names another configuration or rig than this run's
        (``recorded``: both must be there, as in this loop's own checkpoints)."""
        mine = self.config.to_dict()
        if (recorded or "config" in meta) and meta.get("config") != mine:
            theirs = meta.get("config") or {}
            sections = sorted(k for k in {*mine, *theirs} if mine.get(k) != theirs.get(k))
            raise CheckpointError(
                f"{what} was trained with another model configuration (differs in: {', '.join(sections)})"
            )
        if (recorded or "rig_hash" in meta) and meta.get("rig_hash") != self.rig.hash:
            raise CheckpointError(
                f"{what} was trained for rig {meta.get('rig')!r} ({meta.get('rig_hash')}), "
                f"not {self.rig.name!r} ({self.rig.hash})"
            )

    # -- training ---------------------------------------------------------------------------

    def int8_step(self, step: int) -> bool:
        """Whether step ``step``'s forward simulates the int8 file (a seeded draw at rate ``options.qat``)."""
        return self.fake_quant is not None and bool(
            np.random.default_rng([self.options.seed, step]).random() < self.options.qat
        )

    def train_step(self, batch: Batch | None = None) -> dict[str, float]:
        """One optimiser step on the next step's frames (``batch``, or rendered here); returns the loss
        terms, the learning rate and the seconds it took."""
        start, cpu = time.perf_counter(), time.process_time()
        batch = self.train_batches[self.step] if batch is None else batch
        for group in self.optimizer.param_groups:
            group["lr"] = self.options.lr * lr_factor(self.step, self.options.steps, self.options.warmup_steps)
        int8 = self.int8_step(self.step)
        if self.fake_quant is not None:
            self.fake_quant.enabled = int8
        self.model.train()
        if self.options.freeze_backbone:
            for prefix in BACKBONE_PREFIXES:
                self.model.get_submodule(prefix.rstrip(".")).eval()  # BatchNorm statistics stay as they started
        terms = self.objective(batch, self.device)
        self.optimizer.zero_grad(set_to_none=True)
        terms["loss"].backward()
        grad_norm = torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.options.grad_clip)
        self.optimizer.step()
        self.step += 1
        row = {k: float(terms[k].detach()) for k in self.objective.terms}
        row.update(
            step=self.step,
            lr=self.optimizer.param_groups[0]["lr"],
            grad_norm=float(grad_norm),
            int8=int8,
            seconds=time.perf_counter() - start,
            cpu_seconds=time.process_time() - cpu,
        )
        return row

    @torch.no_grad()
    def validate(self) -> dict[str, float]:
        """Mean loss terms on the first ``val_frames`` validation frames, with the model in inference mode (float)."""
        self.model.eval()
        if self.fake_quant is not None:
            self.fake_quant.enabled = False
        sums = dict.fromkeys(self.objective.terms, 0.0)
        for i in range(self.options.val_frames):
            terms = self.objective(self.val_batches[i], self.device)
            for k in self.objective.terms:
                sums[k] += float(terms[k]) / self.options.val_frames
        return sums

    def run(
        self, resume: bool = False, until: int | None = None, progress: Callable[[str], None] | None = None
    ) -> Path:
        """Train up to ``options.steps`` (or stop after step ``until``, to go on later with ``resume``),
        checkpointing every ``checkpoint_every`` steps and where it stops; returns ``model.pth``."""
        self.out.mkdir(parents=True, exist_ok=True)
        if resume:
            self.resume()
        else:
            if self.options.freeze_backbone and not (self.options.init or self.options.init_backbone):
                raise ConfigError("--freeze-backbone keeps the backbone as it starts: give --init-backbone or --init")
            if self.options.init:
                self.load_init()
            elif self.options.init_backbone:
                self.load_backbone()
            write_config(self.config, self.out / "config.py")
            self.rig.save(self.out / "rig.json")
            (self.out / "log.jsonl").write_text("")
        stop = self.options.steps if until is None else min(int(until), self.options.steps)
        bar = ProgressBar(self.options.steps, self.step, self.objective.terms, progress)
        with (self.out / "log.jsonl").open("a") as log:
            for batch in self._batches(stop):
                row = self.train_step(batch)
                log.write(json.dumps(row) + "\n")
                log.flush()
                bar.update(row)
                if self.step % self.options.checkpoint_every == 0 or self.step == stop:
                    if self.options.val_frames:
                        terms = self.validate()
                        log.write(json.dumps({"step": self.step, "split": "val", **terms}) + "\n")
                        bar.note(f"step {self.step}: validation {_terms(terms, self.objective.terms)}")
                    bar.note(f"step {self.step}: wrote {self.save()}")
        bar.close()
        self.objective.settle()
        if self.fake_quant is not None:
            self.fake_quant.enabled = False  # the trained model, as the checkpoint holds it
        return self.out / "model.pth"

    def _batches(self, stop: int) -> torch.utils.data.DataLoader[Batch]:
        """The frames of steps ``self.step`` .. ``stop - 1``, in order, rendered ahead by ``workers`` processes."""
        return step_loader(self.train_batches, self.step, stop, self.workers)


class ProgressBar:
    """One redrawn status line: step, bar, smoothed loss terms, seconds per step and time left."""

    WIDTH = 24

    def __init__(self, total: int, done: int, terms: tuple[str, ...], write: Callable[[str], None] | None) -> None:
        import sys

        self.total, self.done, self.terms = total, done, terms
        self.mean: dict[str, float] = {}
        self.write = write or (lambda text: (sys.stderr.write(text), sys.stderr.flush()))
        self.seconds: float | None = None

    def update(self, row: dict[str, float]) -> None:
        self.done = int(row["step"])
        for k in self.terms:
            self.mean[k] = row[k] if k not in self.mean else 0.9 * self.mean[k] + 0.1 * row[k]
        self.seconds = row["seconds"] if self.seconds is None else 0.9 * self.seconds + 0.1 * row["seconds"]
        filled = int(self.WIDTH * self.done / self.total)
        left = (self.total - self.done) * self.seconds
        self.write(
            f"\r{self.done}/{self.total} [{'#' * filled}{'.' * (self.WIDTH - filled)}] {_terms(self.mean, self.terms)} "
            f"{self.seconds:.1f} s/step, {left / 60:.0f} min left "
        )

    def note(self, text: str) -> None:
        self.write(f"\n{text}\n")

    def close(self) -> None:
        self.write("\n")


def _terms(values: dict[str, float], names: tuple[str, ...]) -> str:
    """``loss 1.234 (cls 0.5 bbox 0.7 ...)``: the loss and its terms, short names."""
    parts = [f"{n.removeprefix('loss_')} {values[n]:.3f}" for n in names if n != "loss"]
    return f"loss {values['loss']:.3f} ({' '.join(parts)})"
