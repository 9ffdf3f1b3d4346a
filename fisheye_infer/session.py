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
from typing import Any

import onnxruntime as ort

from fisheye_infer.errors import ArtifactError, InferenceError

__all__ = ["PREFERRED_PROVIDERS", "Provider", "available_providers", "resolve_providers", "provider_name", "session_options", "create_session",
           "map_ort_errors"]

#: Accelerated providers tried in this order when ``providers="auto"``; CPU always comes last.
PREFERRED_PROVIDERS = ("TensorrtExecutionProvider", "CUDAExecutionProvider", "OpenVINOExecutionProvider", "CPUExecutionProvider")


def available_providers() -> list[str]:
    return list(ort.get_available_providers())


#: A provider by name, or with its options as ONNX Runtime takes them: ``("CUDAExecutionProvider", {"use_tf32": "0"})``.
Provider = str | tuple[str, dict[str, Any]]


def resolve_providers(providers: str | Sequence[Provider] | None) -> list[Provider]:
    """``None`` -> CPU; ``"auto"`` -> the installed accelerated providers, then CPU; else as given (checked)."""
    installed = available_providers()
    if providers is None:
        return ["CPUExecutionProvider"]
    if providers == "auto":
        return [p for p in PREFERRED_PROVIDERS if p in installed]
    wanted: list[Provider] = [providers] if isinstance(providers, str) else list(providers)
    for p in wanted:
        if not (isinstance(p, str) or (isinstance(p, tuple) and len(p) == 2 and isinstance(p[0], str) and isinstance(p[1], dict))):
            raise ValueError(f"providers: expected a provider name or a (name, options dict) pair, got {p!r}")
    missing = [name for name in map(provider_name, wanted) if name not in installed]
    if missing:
        raise ValueError(f"providers: {', '.join(missing)} not offered by the installed onnxruntime (available: {', '.join(installed)})")
    return wanted


def provider_name(provider: Provider) -> str:
    return provider if isinstance(provider, str) else provider[0]


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


def create_session(path: str | Path, threads: int | None = None, providers: str | Sequence[Provider] | None = None) -> ort.InferenceSession:
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
