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

A run folder holds:

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

from ..fisheye_bevdet import FisheyeBEVDet
from ..fisheye_petr import FisheyePETR
from ..view_transform import FisheyeLSS, RectifiedLSS
from .batches import Batch, StepBatches, step_loader
from .config_file import write_config
from .lens_jitter import LensGeometry, LensJitter
from .objectives import objective_for
from .options import TrainOptions, lr_factor, training_device
from .progress import ProgressBar, loss_terms
from .qat import FakeQuant
from .run_checkpoints import (
    BACKBONE_PREFIXES,
    atomic_save,
    backbone_state,
    check_origin,
    grown_queries,
    recorded_options,
    saved_options,
)
from .trainable import TRAINABLE, arch_of, read_config_file

__all__ = ["Trainer", "TRAINABLE", "arch_of", "read_config_file", "saved_options"]


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
        atomic_save(
            {"state_dict": state, "meta": meta, "optimizer": self.optimizer.state_dict(), "fake_quant": fake_quant},
            self.out / "checkpoint.pth",
        )
        atomic_save({"state_dict": state, "meta": meta}, self.out / "model.pth")
        return self.out / "model.pth"

    def resume(self) -> int:
        """Load ``checkpoint.pth`` of this run folder; refuse one made with other options or another configuration."""
        from fisheye_infer.models import load_official_state_dict

        path = self.out / "checkpoint.pth"
        if not path.is_file():
            raise CheckpointError(f"--resume: {path} does not exist (start the run without --resume)")
        ckpt = torch.load(path, map_location="cpu", weights_only=True)
        meta = ckpt.get("meta", {})
        check_origin(meta, self.config, self.rig, f"--resume: {path}", recorded=True)
        saved = recorded_options(meta)
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
        state_dict, meta = grown_queries(self.model, self.config, *load_checkpoint(path))
        check_origin(meta, self.config, self.rig, f"--init: {path}", recorded=False)
        load_official_state_dict(self.model, state_dict, geometry="rig", context=f"--init {path}")

    def load_backbone(self) -> None:
        """Start the image backbone and neck (``img_backbone.*``, ``img_neck.*``) from ``options.init_backbone``,
        a checkpoint of any architecture with the same backbone section; the rest keeps its seeded weights."""
        from fisheye_infer.models import load_checkpoint

        path = Path(self.options.init_backbone)
        if not path.is_file():
            raise CheckpointError(f"--init-backbone: {path} does not exist")
        state_dict, _meta = load_checkpoint(path)
        self.model.load_state_dict(backbone_state(self.model, state_dict, path), strict=False)

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
                        bar.note(f"step {self.step}: validation {loss_terms(terms, self.objective.terms)}")
                    bar.note(f"step {self.step}: wrote {self.save()}")
        bar.close()
        self.objective.settle()
        if self.fake_quant is not None:
            self.fake_quant.enabled = False  # the trained model, as the checkpoint holds it
        return self.out / "model.pth"

    def _batches(self, stop: int) -> torch.utils.data.DataLoader[Batch]:
        """The frames of steps ``self.step`` .. ``stop - 1``, in order, rendered ahead by ``workers`` processes."""
        return step_loader(self.train_batches, self.step, stop, self.workers)
