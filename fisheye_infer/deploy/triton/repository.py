"""An exported ONNX file -> a Triton model repository, for Triton's ONNX Runtime backend or its Python backend.

    write_repository("model.onnx", "model_repository", TritonOptions(max_batch_size=4, instances=2))
    write_repository("model.onnx", "model_repository", TritonOptions(backend="python"))

    model_repository/
      <name>/
        config.pbtxt      inputs and outputs read from the file, dynamic batching, instance groups,
                          optional TensorRT, the fisheye-infer metadata as a parameter
        1/model.onnx      the file, copied byte for byte
        1/model.py        backend="python" only: the model of ``python_backend`` (ONNX Runtime on the CPU,
                          the runtime's session and checks)

The two forms take the same inputs and give the same outputs. The ONNX Runtime form is for Triton's own
images (GPU instances, TensorRT); the Python form is for a server without that backend (the ``tritonserver``
that the ``nvidia-pytriton`` wheel bundles: ``fisheye_infer.deploy.triton.server``) and for CPU deployments that
want the runtime's checks of each request.

The configuration is first built as a plain dict in the JSON form of Triton's ``ModelConfig``
(what Triton answers at ``GET /v2/models/<name>/config``), then rendered to protobuf text
format. The service's KServe stand-in answers that request from the same dict, and a
``TritonDetector`` reads the model's metadata (classes, cameras, image size) from it, so a
client needs nothing but the server's address and the model's name. Nothing here needs
protobuf or tritonclient: the tests parse the rendered text with Triton's own ``ModelConfig``.
"""

from __future__ import annotations

import re
import shutil
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from fisheye_infer.deploy.triton.python_backend import MODEL_PY
from fisheye_infer.errors import ArtifactError, ExportError
from fisheye_infer.runtime.artifact import METADATA_KEY, inspection_session, parse_meta
from fisheye_infer.runtime.detector import check_interface

__all__ = [
    "TritonOptions",
    "model_name",
    "model_config",
    "render_pbtxt",
    "write_repository",
    "TRITON_DTYPES",
    "KSERVE_DTYPES",
]

#: ONNX Runtime element types -> Triton config data types.
TRITON_DTYPES = {
    "tensor(uint8)": "TYPE_UINT8",
    "tensor(bool)": "TYPE_BOOL",
    "tensor(float)": "TYPE_FP32",
    "tensor(int64)": "TYPE_INT64",
    "tensor(int32)": "TYPE_INT32",
    "tensor(float16)": "TYPE_FP16",
    "tensor(double)": "TYPE_FP64",
}
#: Triton config data types -> KServe v2 tensor data types (``TYPE_FP32`` -> ``FP32``).
KSERVE_DTYPES = {v: v.removeprefix("TYPE_") for v in TRITON_DTYPES.values()}

_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*$")
_ENUM_FIELDS = {"data_type", "kind"}  # their string values are enum names, written unquoted
_MAP_FIELDS = {"parameters"}  # written as repeated {key, value} entries


@dataclass(frozen=True)
class TritonOptions:
    """How Triton should run the model: the repository form, batching, instances and TensorRT.

    Attributes:
        name (str | None): The model's name in the repository and in URLs (letters, digits, ``_``, ``.``, ``-``);
            None for the file's stem ([`model_config`][fisheye_infer.deploy.triton.repository.model_config]).
        backend (str): ``onnxruntime`` (Triton's ONNX Runtime backend) or ``python`` (the runtime in Triton's Python
            backend, [`TritonPythonModel`][fisheye_infer.deploy.triton.python_backend.TritonPythonModel]; CPU only).
        max_batch_size (int): Frames per batched run; 0 turns batching off (the batch axis is then part of the
            dims).
        max_queue_delay_us (int): Dynamic batching: how long a request waits for others, in microseconds.
        preferred_batch_sizes (tuple[int, ...]): Dynamic batching: batch sizes to form when possible, each in
            ``1..max_batch_size``; empty for Triton's choice.
        instances (int): Model instances per device; at least 1.
        kind (str): Where instances run: ``cpu``, ``gpu`` or ``auto`` (GPU when present).
        gpus (tuple[int, ...]): GPU ids for ``kind="gpu"``; empty for all.
        threads (int | None): ONNX Runtime intra-op threads per instance; None for the backend's default.
        tensorrt (bool): TensorRT as the GPU execution accelerator (needs ``kind="gpu"``).
        tensorrt_precision (str): TensorRT's precision, ``FP32`` or ``FP16``.
        tensorrt_workspace_bytes (int): TensorRT's scratch memory, in bytes (default 1 GiB).
        tensorrt_cache (str | None): Folder where TensorRT engines are cached across restarts; None for no cache.

    Raises:
        ValueError: A value is out of its range, or the options contradict each other (``tensorrt`` or ``gpus``
            without ``kind="gpu"``, the ``python`` backend with GPU instances).
    """

    name: str | None = None
    backend: Literal["onnxruntime", "python"] = "onnxruntime"
    max_batch_size: int = 4
    max_queue_delay_us: int = 5000
    preferred_batch_sizes: tuple[int, ...] = ()
    instances: int = 1
    kind: Literal["auto", "cpu", "gpu"] = "auto"
    gpus: tuple[int, ...] = ()
    threads: int | None = None
    tensorrt: bool = False
    tensorrt_precision: Literal["FP32", "FP16"] = "FP16"
    tensorrt_workspace_bytes: int = 1 << 30
    tensorrt_cache: str | None = None

    def __post_init__(self) -> None:
        if self.name is not None and not _NAME.match(self.name):
            raise ValueError(
                f"name: {self.name!r} is not a usable model name "
                "(letters, digits, '_', '.', '-'; not starting with '.' or '-')"
            )
        if self.backend not in ("onnxruntime", "python"):
            raise ValueError(f"backend: expected onnxruntime or python, got {self.backend!r}")
        if self.backend == "python" and (self.kind == "gpu" or self.tensorrt):
            raise ValueError("backend: the python form runs ONNX Runtime on the CPU; use kind='cpu' or 'auto'")
        if self.max_batch_size < 0:
            raise ValueError(f"max_batch_size: expected 0 (no batching) or more, got {self.max_batch_size}")
        if self.max_queue_delay_us < 0:
            raise ValueError(f"max_queue_delay_us: expected 0 or more, got {self.max_queue_delay_us}")
        bad = [b for b in self.preferred_batch_sizes if not 1 <= b <= self.max_batch_size]
        if bad:
            raise ValueError(f"preferred_batch_sizes: {bad} outside 1..max_batch_size={self.max_batch_size}")
        if self.instances < 1:
            raise ValueError(f"instances: expected at least 1, got {self.instances}")
        if self.kind not in ("auto", "cpu", "gpu"):
            raise ValueError(f"kind: expected auto, cpu or gpu, got {self.kind!r}")
        if self.gpus and self.kind != "gpu":
            raise ValueError(f"gpus: only for kind='gpu', got kind={self.kind!r}")
        if self.threads is not None and self.threads < 1:
            raise ValueError(f"threads: expected a positive number, got {self.threads}")
        if self.tensorrt and self.kind != "gpu":
            raise ValueError(f"tensorrt: TensorRT runs on GPU instances; set kind='gpu' (got kind={self.kind!r})")
        if self.tensorrt_precision not in ("FP32", "FP16"):
            raise ValueError(f"tensorrt_precision: expected FP32 or FP16, got {self.tensorrt_precision!r}")
        if self.tensorrt_workspace_bytes < 1:
            raise ValueError(f"tensorrt_workspace_bytes: expected a positive size, got {self.tensorrt_workspace_bytes}")


def model_name(path: str | Path) -> str:
    """The default model name for a file: its stem, with characters Triton cannot use replaced by '_'."""
    stem = re.sub(r"[^A-Za-z0-9_.-]", "_", Path(path).stem).lstrip(".-")
    return stem or "model"


def _io(items: list[Any], batched: bool, source: str) -> list[dict[str, Any]]:
    out = []
    for item in items:
        if item.type not in TRITON_DTYPES:
            raise ArtifactError(
                f"{source}: tensor '{item.name}' has type {item.type}, which this writer does not map to Triton"
            )
        shape = [d if isinstance(d, int) and d > 0 else -1 for d in item.shape]
        if batched:
            if shape[0] != -1:
                raise ExportError(
                    f"{source}: tensor '{item.name}' has a fixed batch of {shape[0]}; use max_batch_size=0"
                )
            shape = shape[1:]
        out.append({"name": item.name, "data_type": TRITON_DTYPES[item.type], "dims": shape})
    return out


def model_config(model_path: str | Path, options: TritonOptions | None = None) -> dict[str, Any]:
    """The Triton ``ModelConfig`` of an exported file, as a dict in its JSON form.

    This is what Triton answers at ``GET /v2/models/<name>/config`` and what ``config.pbtxt`` holds in protobuf text
    format; the model's name defaults to the file's stem with characters Triton cannot use replaced by ``_``.

    Args:
        model_path (str | Path): An ONNX file written by ``fisheye-infer export``.
        options (TritonOptions | None): The repository form and how Triton runs the model; None for
            ``TritonOptions()``.

    Returns:
        dict: The configuration in the JSON form of Triton's ``ModelConfig``.

    Raises:
        ArtifactError: The file is not a fisheye-infer model, or a tensor's type has no Triton data type.
        ExportError: A tensor's batch axis is fixed while ``max_batch_size`` asks for batching.
    """
    options = options or TritonOptions()
    path = Path(model_path)
    session = inspection_session(path)
    document = session.get_modelmeta().custom_metadata_map.get(METADATA_KEY)
    meta = parse_meta(document, source=f"model {path}")
    check_interface(
        {i.name: i.shape for i in session.get_inputs()}, [o.name for o in session.get_outputs()], meta, f"model {path}"
    )
    batched = options.max_batch_size > 0
    config: dict[str, Any] = {
        "name": options.name or model_name(path),
        "backend": options.backend,
        **({"default_model_filename": "model.onnx"} if options.backend == "onnxruntime" else {}),
        "max_batch_size": options.max_batch_size,
        "input": _io(session.get_inputs(), batched, f"model {path}"),
        "output": _io(session.get_outputs(), batched, f"model {path}"),
    }
    if batched:
        batching: dict[str, Any] = {"max_queue_delay_microseconds": options.max_queue_delay_us}
        if options.preferred_batch_sizes:
            batching["preferred_batch_size"] = list(options.preferred_batch_sizes)
        config["dynamic_batching"] = batching
    kind = "cpu" if options.backend == "python" else options.kind
    group: dict[str, Any] = {
        "count": options.instances,
        "kind": {"auto": "KIND_AUTO", "cpu": "KIND_CPU", "gpu": "KIND_GPU"}[kind],
    }
    if options.gpus:
        group["gpus"] = list(options.gpus)
    config["instance_group"] = [group]
    if options.tensorrt:
        trt = {
            "precision_mode": options.tensorrt_precision,
            "max_workspace_size_bytes": str(options.tensorrt_workspace_bytes),
        }
        if options.tensorrt_cache:
            trt |= {"trt_engine_cache_enable": "1", "trt_engine_cache_path": options.tensorrt_cache}
        config["optimization"] = {
            "execution_accelerators": {"gpu_execution_accelerator": [{"name": "tensorrt", "parameters": trt}]}
        }
    parameters = {METADATA_KEY: {"string_value": document}}
    if options.backend == "onnxruntime":
        # The runtime's own choice (session.py): no memory-pattern planning, which keeps peak RSS low.
        parameters["enable_mem_pattern"] = {"string_value": "0"}
    if options.threads:
        parameters["intra_op_thread_count"] = {"string_value": str(options.threads)}
    config["parameters"] = parameters
    return config


# -- protobuf text format --------------------------------------------------------------------------


def _quote(text: str) -> str:
    """A text-format string literal: printable ASCII as is (quote and backslash escaped), other bytes of its UTF-8
    as octal escapes."""
    out = []
    for byte in text.encode("utf-8"):
        if byte in (34, 92):
            out.append("\\" + chr(byte))
        else:
            out.append(chr(byte) if 32 <= byte < 127 else f"\\{byte:03o}")
    return '"' + "".join(out) + '"'


def _scalar(key: str, value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        return repr(value)
    if isinstance(value, str):
        return value if key in _ENUM_FIELDS else _quote(value)
    raise TypeError(f"{key}: cannot write {type(value).__name__} in text format")


def _fields(doc: dict[str, Any], indent: int) -> list[str]:
    pad = "  " * indent
    lines: list[str] = []
    for key, value in doc.items():
        if key in _MAP_FIELDS and isinstance(value, dict):
            for k, v in value.items():
                entry = {"key": k, "value": v}
                lines += [f"{pad}{key} {{", *_fields(entry, indent + 1), f"{pad}}}"]
        elif isinstance(value, dict):
            lines += [f"{pad}{key} {{", *_fields(value, indent + 1), f"{pad}}}"]
        elif isinstance(value, list) and value and all(isinstance(v, dict) for v in value):
            for item in value:
                lines += [f"{pad}{key} {{", *_fields(item, indent + 1), f"{pad}}}"]
        elif isinstance(value, list):
            lines.append(f"{pad}{key}: [{', '.join(_scalar(key, v) for v in value)}]")
        else:
            lines.append(f"{pad}{key}: {_scalar(key, value)}")
    return lines


def render_pbtxt(config: dict[str, Any]) -> str:
    """``config`` (JSON form of ``ModelConfig``) in protobuf text format, as ``config.pbtxt``."""
    return "\n".join(_fields(config, 0)) + "\n"


def write_repository(
    model_path: str | Path, out: str | Path, options: TritonOptions | None = None, *, force: bool = False
) -> Path:
    """Write the model folder ``out/<name>`` of an exported file into a Triton model repository.

    The folder holds ``config.pbtxt`` (inputs and outputs read from the file, batching, instance groups, optional
    TensorRT, the fisheye-infer metadata as a parameter), ``1/model.onnx`` (the file, copied byte for byte) and, for
    ``backend="python"``, ``1/model.py``. The model folder appears complete or not at all (it is built beside its
    place and renamed), and an existing one is replaced only with ``force``.

    Args:
        model_path (str | Path): An ONNX file written by ``fisheye-infer export``.
        out (str | Path): The model repository (created; other models in it are left alone).
        options (TritonOptions | None): The repository form and how Triton runs the model; None for
            ``TritonOptions()``.
        force (bool): Replace an existing model folder of the same name.

    Returns:
        Path: The model folder.

    Raises:
        ExportError: The folder exists and ``force`` is not given, or the file's batch axis is fixed while batching.
        ArtifactError: The file is not a fisheye-infer model.

    Examples:
        ```python
        from fisheye_infer.deploy.triton.repository import TritonOptions, write_repository

        write_repository("model.onnx", "model_repository", TritonOptions(max_batch_size=4, instances=2))
        # tritonserver --model-repository=model_repository
        ```
    """
    config = model_config(model_path, options)
    root = Path(out)
    target = root / config["name"]
    if target.exists() and not force:
        raise ExportError(f"{target}: already exists; choose another --name or pass --force to replace it")
    root.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{config['name']}.", dir=root))
    try:
        (staging / "1").mkdir()
        shutil.copyfile(model_path, staging / "1" / "model.onnx")
        if config["backend"] == "python":
            (staging / "1" / "model.py").write_text(MODEL_PY)
        (staging / "config.pbtxt").write_text(render_pbtxt(config))
        if target.exists():
            shutil.rmtree(target)
        staging.rename(target)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return target
