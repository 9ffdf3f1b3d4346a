"""ONNX Runtime sessions: providers, threads, and one place where ORT's errors are translated.

Defaults measured on a 2-core CPU (see the README's performance notes): all graph
optimisations at load time (the file itself stays portable), one inter-op thread, and as many
intra-op threads as the machine has cores unless told otherwise.
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import onnxruntime as ort

from fisheye_infer.errors import ArtifactError, InferenceError

__all__ = ["PREFERRED_PROVIDERS", "available_providers", "resolve_providers", "session_options", "create_session", "map_ort_errors"]

#: Accelerated providers tried in this order when ``providers="auto"``; CPU always comes last.
PREFERRED_PROVIDERS = ("TensorrtExecutionProvider", "CUDAExecutionProvider", "OpenVINOExecutionProvider", "CPUExecutionProvider")


def available_providers() -> list[str]:
    return list(ort.get_available_providers())


def resolve_providers(providers: str | Sequence[str] | None) -> list[str]:
    """``None`` -> CPU; ``"auto"`` -> the installed accelerated providers, then CPU; else as given (checked)."""
    installed = available_providers()
    if providers is None:
        return ["CPUExecutionProvider"]
    if providers == "auto":
        return [p for p in PREFERRED_PROVIDERS if p in installed]
    wanted = [providers] if isinstance(providers, str) else list(providers)
    missing = [p for p in wanted if p not in installed]
    if missing:
        raise ValueError(f"providers: {', '.join(missing)} not offered by the installed onnxruntime (available: {', '.join(installed)})")
    return wanted


def session_options(threads: int | None = None) -> ort.SessionOptions:
    """The project's session options (also used by ``fisheye-infer bench`` for stage models)."""
    if threads is not None and threads < 1:
        raise ValueError(f"threads: expected a positive number, got {threads}")
    options = ort.SessionOptions()
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.inter_op_num_threads = 1
    options.intra_op_num_threads = int(threads) if threads else (os.cpu_count() or 1)
    options.log_severity_level = 3
    # Memory-pattern planning keeps a peak-sized block per input shape: FisheyeBEVDet's peak RSS
    # drops from about 980 MB to 610 MB without it, at the same latency (measured on 2 cores).
    options.enable_mem_pattern = False
    return options


def create_session(path: str | Path, threads: int | None = None, providers: str | Sequence[str] | None = None) -> ort.InferenceSession:
    """An inference session with the project's defaults; ``threads`` sets intra-op parallelism."""
    options = session_options(threads)
    try:
        return ort.InferenceSession(str(path), options, providers=resolve_providers(providers))
    except ValueError:
        raise
    except Exception as exc:  # onnxruntime raises untyped RuntimeErrors for bad files
        raise ArtifactError(f"model {path}: ONNX Runtime cannot load it ({exc})") from exc


@contextmanager
def map_ort_errors(context: str) -> Iterator[None]:
    """Re-raise anything ONNX Runtime throws while running as ``InferenceError``."""
    try:
        yield
    except Exception as exc:
        raise InferenceError(f"{context}: ONNX Runtime failed: {exc}") from exc
