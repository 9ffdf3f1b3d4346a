"""What an export returns: the files written, their metadata and parity, and a summary for people.

``ExportResult`` describes the fp32 file and holds the ``Int8Result`` and ``Fp16Result`` of the
reduced-precision files made from it; each ``summary()`` is what ``fisheye-infer export`` prints.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from fisheye_infer.runtime.artifact import ArtifactMeta, ParityReport, ReducedParityReport

from .int8_search import search_table

__all__ = ["ExportResult", "Fp16Result", "Int8Result", "ReducedResult"]


@dataclass(frozen=True)
class ReducedResult:
    """A reduced-precision file derived from a verified fp32 file, and how it compared.

    Attributes:
        path (Path | None): The written file; None when it was not written (its comparison failed).
        meta (ArtifactMeta): The file's metadata, with its parity report and ``quantization`` record.
        parity (ReducedParityReport): The comparison with the fp32 file: the share of the fp32 file's top-50 boxes
            found again, and whether that passed.
        seconds (float): How long making and comparing the file took, in seconds.
        file_bytes (int): The written file's size in bytes; 0 when not written.
    """

    path: Path | None
    meta: ArtifactMeta
    parity: ReducedParityReport
    seconds: float
    file_bytes: int


class Int8Result(ReducedResult):
    """The int8 file made from an fp32 file ([`export_int8`][fisheye_infer.export.reduced.export_int8]).

    Its fields are those of [`ReducedResult`][fisheye_infer.export.results.ReducedResult]: ``path``, ``meta``,
    ``parity``, ``seconds``, ``file_bytes``.
    """

    def summary(self) -> str:
        """What ``fisheye-infer export --int8`` prints for the file.

        Returns:
            str: Lines on the file, how it was quantized, its comparison with the fp32 file, the int8 search and the
                TensorRT check.
        """
        p, q = self.parity, self.meta.quantization
        how = (
            f"{q.mode}, {q.scope}, {q.weight_bits}-bit weights, calibrated on {q.calibration_frames} frame(s)"
            if q is not None
            else "not quantized"
        )
        return "\n".join(
            [
                f"int8 {'wrote' if self.path else 'not written'}: {self.path or '-'}  ({self.file_bytes / 1e6:.1f} MB; "
                f"{how})",
                f"int8 vs the fp32 ONNX file on {p.frames} frames: {_kept(p)} of the top-50 boxes matched within "
                f"{p.match_radius_m:g} m with the same label (need {p.min_top_matched:.0%}) -> "
                f"{'PASSED' if p.passed else 'FAILED'}; took {self.seconds:.1f} s",
                *_by_score_lines(p),
                *_search_lines(self.meta),
                *_tensorrt_lines(self.meta, "int8 file: "),
            ]
        )


class Fp16Result(ReducedResult):
    """The fp16 file made from an fp32 file ([`export_fp16`][fisheye_infer.export.reduced.export_fp16]).

    Its fields are those of [`ReducedResult`][fisheye_infer.export.results.ReducedResult]: ``path``, ``meta``,
    ``parity``, ``seconds``, ``file_bytes``.
    """

    def summary(self) -> str:
        """What ``fisheye-infer export --fp16`` prints for the file.

        Returns:
            str: Lines on the file, its comparison with the fp32 file and the TensorRT check.
        """
        p, q = self.parity, self.meta.quantization
        lines = [
            f"fp16 {'wrote' if self.path else 'not written'}: {self.path or '-'}  ({self.file_bytes / 1e6:.1f} MB; "
            f"{q.scope if q else 'not reduced'})",
            f"fp16 vs the fp32 ONNX file on {p.frames} frames ({p.evaluated_with}): {_kept(p)} of the top-50 boxes "
            f"matched within {p.match_radius_m:g} m with the same label (need {p.min_top_matched:.0%}; matched max "
            f"|box| {p.max_box_abs_diff_m:.3f} m, |score| {p.max_score_abs_diff:.4f}) -> "
            f"{'PASSED' if p.passed else 'FAILED'}; took {self.seconds:.1f} s",
            *_by_score_lines(p),
        ]
        if p.replayed is not None:
            r = p.replayed
            lines.append(
                f"  at the fp16 file's own top-k choice: {r.top_matched_fraction:.1%} matched; position by position "
                f"max |box| {r.max_box_abs_diff_m:.3f} m, |score| {r.max_score_abs_diff:.4f}; dense scores max |diff| "
                f"{p.max_rank_score_abs_diff or 0.0:.4f}"
            )
        lines += [f"  {problem}" for problem in p.problems]
        return "\n".join(lines + _tensorrt_lines(self.meta, "fp16 file: "))


def _kept(p: ReducedParityReport) -> str:
    """ "91.2% +- 1.1%": the share of the fp32 top-50 boxes found again and its standard error over the frames."""
    spread = f" +- {p.top_matched_standard_error:.1%}" if p.top_matched_standard_error else ""
    return f"{p.top_matched_fraction:.1%}{spread}"


def _by_score_lines(p: ReducedParityReport) -> list[str]:
    """The share kept per band of the fp32 box's score: what a detection threshold would keep."""
    if not p.top_matched_by_score:
        return []
    bands = [f"{band} {m / c:.1%} of {c}" for band, (m, c) in p.top_matched_by_score.items() if c]
    return ["  by the fp32 box's score: " + ", ".join(bands)]


def _search_lines(meta: ArtifactMeta) -> list[str]:
    """What the int8 search tried and chose: the table, what stayed float32 and the speed-up it measured."""
    q = meta.quantization
    if q is None or q.search is None:
        return []
    search = q.search
    p = meta.parity
    assert isinstance(p, ReducedParityReport)  # an int8 file's parity is against its fp32 file
    if search.chosen is None:
        head = f"int8 search: no trial passed ({len(search.trials)} tried in {search.seconds:.0f} s):"
    else:
        trial = search.trials[search.chosen]
        floats = ", ".join(trial.float_modules) or "no module"
        head = (
            f"int8 search: trial {search.chosen + 1} of {len(search.trials)} ({search.seconds:.0f} s): scope "
            f"{trial.scope}, float32: {floats}; {search.speedup:.2f}x the fp32 file's speed on this machine "
            f"({search.cpu}, {search.threads} thread(s))"
        )
    return [head, *search_table(search, p.min_top_matched)]


def _tensorrt_lines(meta: ArtifactMeta, prefix: str = "") -> list[str]:
    return [prefix + meta.tensorrt.summary()] if meta.tensorrt is not None else []


@dataclass(frozen=True)
class ExportResult:
    """What [`export`][fisheye_infer.export.exporter.export] returns: the fp32 file, its check, the reduced files.

    Attributes:
        path (Path | None): The written fp32 file; None when it was not written (its parity check failed).
        meta (ArtifactMeta): The file's metadata
            ([`ArtifactMeta`][fisheye_infer.runtime.artifact.ArtifactMeta]), parity report included.
        parity (ParityReport): The check of the ONNX file against PyTorch in float64: largest differences,
            tolerances and whether it passed.
        seconds (float): How long the export took, in seconds (reduced files included).
        file_bytes (int): The fp32 file's size in bytes; 0 when not written.
        initializer_bytes (int): Bytes of every initializer: weights and geometry tables.
        geometry_bytes (int): Bytes of the ``geom.*`` initializers alone.
        int8 (Int8Result | None): The int8 file's result
            ([`Int8Result`][fisheye_infer.export.results.Int8Result]); None when not asked for.
        fp16 (Fp16Result | None): The fp16 file's result
            ([`Fp16Result`][fisheye_infer.export.results.Fp16Result]); None when not asked for.
    """

    path: Path | None
    meta: ArtifactMeta
    parity: ParityReport
    seconds: float
    file_bytes: int
    initializer_bytes: int  # every initializer: weights and geometry tables
    geometry_bytes: int  # the ``geom.*`` initializers alone
    int8: Int8Result | None = None
    fp16: Fp16Result | None = None

    def summary(self) -> str:
        """What ``fisheye-infer export`` prints: the files, their checks, and the commands to try next.

        Returns:
            str: The summary, one line per fact, the int8 and fp16 files' summaries included.
        """
        p = self.parity
        lines = [
            f"{'wrote' if self.path else 'not written'}: {self.path or '-'}  ({self.file_bytes / 1e6:.1f} MB; "
            f"initializers {self.initializer_bytes / 1e6:.1f} MB, of which geometry tables "
            f"{self.geometry_bytes / 1e6:.1f} MB)",
            f"model {self.meta.model_id}: {self.meta.architecture}, {len(self.meta.cameras)} cameras at "
            f"{self.meta.image_size[0]}x{self.meta.image_size[1]}, {self.meta.num_boxes} boxes, rig "
            f"{self.meta.rig_hash}",
            f"parity vs PyTorch float64 on {p.frames} frames at {', '.join(map(str, p.threads))} thread(s) "
            f"(PyTorch float32 itself: dense {_f32(p, 0)}, box {_f32(p, 1)} m, score {_f32(p, 2)}):",
            f"  scores before ranking max |diff| {p.max_rank_score_abs_diff or 0.0:.2e} (tol "
            f"{p.tolerance_rank_score or p.tolerance_score:.1e}); top-k choice: {_choice(p)}",
            f"  at that choice max |box| {p.max_box_abs_diff_m:.2e} m (tol {p.tolerance_box_m:.1e}), max |score| "
            f"{p.max_score_abs_diff:.2e} (tol {p.tolerance_score:.1e}), labels "
            f"{'equal' if p.labels_equal else 'DIFFER'}, valid {'equal' if p.valid_equal else 'DIFFERS'}, "
            f"{p.unmatched} box(es) "
            f"off{'; the written file DIFFERS from the checked graph' if p.written_equals_checked is False else ''} -> "
            f"{'PASSED' if p.passed else 'FAILED'}",
            *(f"  {problem}" for problem in p.problems),
            *_tensorrt_lines(self.meta),
            f"took {self.seconds:.1f} s",
        ]
        if self.int8 is not None:
            lines.append(self.int8.summary())
        if self.fp16 is not None:
            lines.append(self.fp16.summary())
        if self.path:
            lines.append(f"next: fisheye-infer detect {self.path} --images DIR --out result.json --viz result.png")
        if self.int8 is not None and self.int8.path:
            lines.append(
                f"      fisheye-infer detect {self.int8.path} ...   (int8); fisheye-infer bench {self.int8.path}"
            )
        if self.fp16 is not None and self.fp16.path:
            lines.append(f"      {self.fp16.path}: for GPU execution providers (CUDA, TensorRT)")
        return "\n".join(lines)


def _f32(p: ParityReport, i: int) -> str:
    return f"{p.pytorch_float32[i]:.1e}" if p.pytorch_float32 else "-"


def _choice(p: ParityReport) -> str:
    """How the graph's top-k choice relates to PyTorch's, in words."""
    if p.order_equal:
        return "PyTorch float32's own"
    if p.selection_valid:
        return (
            "a top-k of its scores, ties broken otherwise than PyTorch float32 "
            f"({p.tie_substitutions} substitution(s), {p.tie_swaps} position(s))"
        )
    return "NOT a top-k of its own scores"
