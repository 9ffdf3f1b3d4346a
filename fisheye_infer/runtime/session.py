"""ONNX Runtime sessions: providers, threads, and one place where ORT's errors are translated.

Defaults: all graph optimisations at load time (the file itself stays portable), one inter-op
thread, and as many intra-op threads as the machine has cores unless told otherwise
(``fisheye-infer bench`` measures the thread counts on a given machine).
"""

from __future__ import annotations

import json
import logging
import numbers
import os
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import onnxruntime as ort

from fisheye_infer.errors import ArtifactError, ConfigError, InferenceError, OptionError
from fisheye_infer.runtime.denormals import flushed_denormals

__all__ = [
    "PREFERRED_PROVIDERS",
    "Provider",
    "available_providers",
    "resolve_providers",
    "parse_providers",
    "provider_name",
    "session_options",
    "create_session",
    "open_session",
    "check_started",
    "map_ort_errors",
    "usable_cpus",
    "THREADS_PER_CPU",
    "check_threads",
]

log = logging.getLogger("fisheye_infer")

#: Accelerated providers tried in this order when ``providers="auto"``; CPU always comes last.
PREFERRED_PROVIDERS = (
    "TensorrtExecutionProvider",
    "CUDAExecutionProvider",
    "OpenVINOExecutionProvider",
    "CPUExecutionProvider",
)


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
    if not isinstance(providers, str) and (isinstance(providers, bytes) or not isinstance(providers, Sequence)):
        raise ConfigError(
            "providers: expected 'auto', a provider name or a list of them (or of (name, options dict) pairs), "
            f"got {type(providers).__name__}"
        )
    wanted: list[Provider] = [providers] if isinstance(providers, str) else list(providers)
    if "auto" in wanted:
        raise ConfigError(
            "providers: 'auto' stands alone (the installed accelerated providers, then CPU), "
            f"got {', '.join(map(str, wanted))}"
        )
    for p in wanted:
        if not (
            isinstance(p, str)
            or (isinstance(p, tuple) and len(p) == 2 and isinstance(p[0], str) and isinstance(p[1], dict))
        ):
            raise ConfigError(f"providers: expected a provider name or a (name, options dict) pair, got {repr(p)[:80]}")
    missing = [name for name in map(provider_name, wanted) if name not in installed]
    if missing:
        raise ConfigError(
            f"providers: {', '.join(missing)} not offered by the installed onnxruntime "
            f"(available: {', '.join(installed)})"
        )
    return wanted


def parse_providers(text: str) -> str | list[Provider]:
    """Providers as a command line or an environment variable gives them, checked (``resolve_providers``):
    ``auto``; names separated by commas; or a JSON list of names and ``[name, {option: value}]`` pairs, for
    provider options (``[["TensorrtExecutionProvider", {"trt_engine_cache_enable": "1"}], "CPUExecutionProvider"]``).
    """
    text = text.strip()
    if text.startswith("["):
        try:
            entries = json.loads(text)
        except json.JSONDecodeError as exc:
            raise ConfigError(f"providers: not a JSON list ({exc})") from None
        if not isinstance(entries, list):
            raise ConfigError(f"providers: expected a JSON list, got {text[:80]}")
        wanted: list[Provider] = [tuple(e) if isinstance(e, list) else e for e in entries]
    else:
        wanted = [name.strip() for name in text.split(",") if name.strip()]
    if wanted == ["auto"]:
        return "auto"
    if not wanted:
        raise ConfigError("providers: none given (names separated by commas, a JSON list, or 'auto')")
    for p in wanted:
        if isinstance(p, tuple) and len(p) == 2 and isinstance(p[1], dict):
            bad = [k for k, v in p[1].items() if not isinstance(v, str | int | float | bool)]
            if bad:
                raise ConfigError(f"providers: {p[0]} option {bad[0]!r}: expected a string, number or boolean")
    return resolve_providers(wanted)


def provider_name(provider: Provider) -> str:
    return provider if isinstance(provider, str) else provider[0]


def usable_cpus() -> int:
    """The CPUs this process may run on (its affinity, which a container's cpuset narrows), else all."""
    try:
        return len(os.sched_getaffinity(0)) or 1
    except (AttributeError, OSError):  # not Linux
        return os.cpu_count() or 1


#: The most threads a pool may have per CPU this process may use: more only waste memory and time switching.
THREADS_PER_CPU = 4


def check_threads(value: object, name: str = "threads") -> int | None:
    """``None`` or a whole number of threads from 1 to ``THREADS_PER_CPU`` x ``usable_cpus()``.

    Args:
        value: what the caller passed (a bool, a float such as 1.5 and a string are refused).
        name: the argument, as the message names it.

    Returns:
        The number as an ``int``, or ``None``.

    Raises:
        OptionError: naming ``name``, the range and what was given.
    """
    if value is None:
        return None
    cpus = usable_cpus()
    most = THREADS_PER_CPU * cpus
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or not 1 <= int(value) <= most:
        shown = repr(value) if len(repr(value)) <= 40 else repr(value)[:37] + "..."
        raise OptionError(
            f"{name}: expected a whole number from 1 to {most} ({THREADS_PER_CPU} x the {cpus} CPU(s) this process "
            f"may use), got {type(value).__name__} {shown}"
        )
    return int(value)


def session_options(threads: int | None = None, spin: bool = True) -> ort.SessionOptions:
    """The project's session options (also used by ``fisheye-infer bench`` for stage models).

    ``spin=False``: the intra-op threads sleep as soon as a call ends. By default (ONNX Runtime's)
    they spin for a while first, ready for the next call: a call a few percent faster, for tens of
    milliseconds of CPU time after every call, taken from whatever else shares the cores (other
    processes on a robot, another model in the same process; ``benchmarks/spinning.py``).
    The worker threads flush denormal floats to zero (``denormals``; run a session inside
    ``flushed_denormals()`` for the calling thread's share).
    """
    threads = check_threads(threads)
    options = ort.SessionOptions()
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    options.inter_op_num_threads = 1
    options.intra_op_num_threads = threads or usable_cpus()
    options.log_severity_level = 3
    # Memory-pattern planning keeps a peak-sized block per input shape: FisheyeBEVDet's peak RSS
    # drops from about 980 MB to 610 MB without it, at the same latency (measured on 2 cores).
    options.enable_mem_pattern = False
    options.add_session_config_entry("session.set_denormal_as_zero", "1")
    if not spin:
        options.add_session_config_entry("session.intra_op.allow_spinning", "0")
    return options


def create_session(
    path: str | Path, threads: int | None = None, providers: str | Sequence[Provider] | None = None, spin: bool = True
) -> ort.InferenceSession:
    """An inference session with the project's defaults; ``threads`` sets intra-op parallelism,
    ``spin`` whether its threads spin for a while after a call (``session_options``).

    Providers named explicitly must start: ONNX Runtime would otherwise fall back to the CPU (a
    CUDA provider without its libraries or a GPU) and say so only in its log. ``"auto"`` takes
    whatever starts, dropping from the front of its list the providers that fail (a warning
    each); ``session.get_providers()`` says what that was.
    """
    options = session_options(threads, spin)
    wanted = resolve_providers(providers)
    while True:
        try:
            with flushed_denormals():  # keeps this thread's floating-point environment (``denormals``)
                session = ort.InferenceSession(str(path), options, providers=wanted, enable_fallback=0)
            break
        except Exception as exc:  # onnxruntime raises untyped RuntimeErrors for bad files
            if providers != "auto" or len(wanted) == 1:
                raise ArtifactError(
                    f"model {path}: ONNX Runtime cannot load it with {', '.join(map(provider_name, wanted))} ({exc})"
                ) from exc
            # onnxruntime-gpu lists TensorRT whether or not its libraries are installed: try the next one
            log.warning(
                "providers auto: %s did not start (%s); trying %s",
                provider_name(wanted[0]),
                str(exc).strip()[:300],
                ", ".join(map(provider_name, wanted[1:])),
            )
            wanted = wanted[1:]
    if providers != "auto":
        check_started(session, wanted, f"model {path}")
    return session


def open_session(
    model: str | bytes, options: ort.SessionOptions, providers: Sequence[Provider], context: str
) -> ort.InferenceSession:
    """A session on exactly ``providers`` (a path or serialized model): no fallback to the CPU (``check_started``)."""
    with flushed_denormals():  # keeps this thread's floating-point environment (``denormals``)
        session = ort.InferenceSession(model, options, providers=list(providers), enable_fallback=0)
    check_started(session, providers, context)
    return session


def check_started(session: ort.InferenceSession, wanted: Sequence[Provider], context: str) -> None:
    """Raise ``ConfigError`` unless every provider asked for is one the session runs with."""
    missing = [name for name in map(provider_name, wanted) if name not in session.get_providers()]
    if missing:
        raise ConfigError(
            f"{context}: ONNX Runtime did not start {', '.join(missing)} "
            f"(the session runs on {', '.join(session.get_providers())}); "
            "its log says why (a CUDA provider needs a GPU, its driver, and the CUDA and cuDNN versions the installed "
            "onnxruntime-gpu was built for)"
        )


@contextmanager
def map_ort_errors(context: str) -> Iterator[None]:
    """Re-raise anything ONNX Runtime throws while running as ``InferenceError``."""
    try:
        yield
    except Exception as exc:
        raise InferenceError(f"{context}: ONNX Runtime failed: {exc}") from exc
