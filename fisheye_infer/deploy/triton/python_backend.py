"""The model of the Python-backend repository form: Triton's Python backend running the exported file in ONNX Runtime.

    <name>/config.pbtxt     backend: "python", the same inputs, outputs and batching as the ONNX Runtime form
    <name>/1/model.py       ``from fisheye_infer.deploy.triton.python_backend import TritonPythonModel``
    <name>/1/model.onnx     the exported file

Triton loads ``model.py`` in its Python backend stub, which runs the Python interpreter the stub was started with
(``fisheye_infer.deploy.triton.server`` starts it with the current one). Tensors cross the stub by DLPack, never by
``as_numpy()`` and ``Tensor(name, array)``: those go through the NumPy C API the stub was built against (NumPy 1),
which misreads NumPy 2 arrays. The session is the runtime's
(``fisheye_infer.runtime.session.create_session``: the project's options, the CPU), its inputs and outputs checked
against the file's metadata when the instance loads. Requests that Triton's dynamic batcher hands over together run
as one batch; a request whose tensors do not fit the file (a missing input, a wrong type or shape, batches that
differ between ``images`` and ``camera_valid``) is answered with an error naming the tensor, and the others run.
"""

from __future__ import annotations

import ctypes
import json
from pathlib import Path
from typing import Any

import numpy as np

from fisheye_infer.errors import FisheyeInferError, FrameError
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, METADATA_KEY, OUTPUTS, parse_meta
from fisheye_infer.runtime.denormals import flushed_denormals
from fisheye_infer.runtime.detector import check_interface
from fisheye_infer.runtime.session import create_session, map_ort_errors

__all__ = ["MODEL_PY", "TritonPythonModel", "check_request"]

#: The repository's ``1/model.py``: Triton finds the class by its name in this module's namespace.
MODEL_PY = (
    '"""Triton Python backend: the exported file beside this one, run by fisheye-infer."""\n\n'
    "from fisheye_infer.deploy.triton.python_backend import TritonPythonModel  # noqa: F401\n"
)

_DTYPES = {INPUT_IMAGES: np.dtype(np.uint8), INPUT_CAMERA_VALID: np.dtype(bool)}
#: DLPack's name for a consumed capsule. The stub renames the capsules it takes "used_dlpack", which NumPy's capsule
#: destructor does not recognise (it then reports an error for every tensor); they are renamed to this after use.
_USED_CAPSULE = ctypes.c_char_p(b"used_dltensor")
_set_capsule_name = ctypes.pythonapi.PyCapsule_SetName
_set_capsule_name.argtypes = (ctypes.py_object, ctypes.c_char_p)


def _output_tensor(pb: Any, name: str, array: np.ndarray) -> Any:
    """A Triton tensor holding ``array`` (shared by DLPack, released by the stub when sent)."""
    capsule = np.ascontiguousarray(array).__dlpack__()
    tensor = pb.Tensor.from_dlpack(name, capsule)
    _set_capsule_name(capsule, _USED_CAPSULE)
    return tensor


def check_request(arrays: dict[str, np.ndarray | None], shapes: dict[str, list[int | None]]) -> int:
    """Check one request's input tensors against the file's inputs.

    Args:
        arrays: Each input's array as the request carries it (None where the request lacks it).
        shapes: Each input's shape in the file, batch axis first (None or a negative size where free).

    Returns:
        int: The request's batch size.

    Raises:
        FrameError: A tensor is missing, of the wrong type or shape, or the inputs' batches differ.
    """
    batches = {}
    for name, shape in shapes.items():
        array = arrays.get(name)
        if array is None:
            raise FrameError(f"input '{name}': missing from the request")
        if array.dtype != _DTYPES[name]:
            raise FrameError(f"input '{name}': expected {_DTYPES[name]}, got {array.dtype}")
        fixed = [d if isinstance(d, int) and d > 0 else -1 for d in shape]
        if array.ndim != len(fixed) or any(d != -1 and d != n for d, n in zip(fixed, array.shape)):
            raise FrameError(f"input '{name}': expected shape {fixed} (-1: any), got {list(array.shape)}")
        batches[name] = array.shape[0]
    if len(set(batches.values())) > 1:
        raise FrameError(f"inputs' batches differ: {batches}")
    return next(iter(batches.values()))


class TritonPythonModel:
    """The model Triton's Python backend loads from the repository's ``1/model.py``.

    [`write_repository`][fisheye_infer.deploy.triton.repository.write_repository] with
    ``TritonOptions(backend="python")`` writes a ``model.py`` that imports this class. Triton calls ``initialize``
    once per instance (it opens ``1/model.onnx`` in ONNX Runtime on the CPU, with the runtime's session options),
    ``execute`` with the requests its dynamic batcher hands over, and ``finalize`` when it unloads the model. Triton
    constructs it without arguments; it is not meant to be called directly.
    """

    def initialize(self, args: dict[str, str]) -> None:
        """Open the file beside ``model.py`` and check it against its metadata.

        Args:
            args (dict[str, str]): Triton's arguments: ``model_config`` (JSON), ``model_repository`` (the model's
                folder), ``model_version``.

        Raises:
            ArtifactError: The file is missing, not a fisheye-infer model, or its interface does not match its metadata.
        """
        import triton_python_backend_utils as pb_utils

        self._pb = pb_utils
        config = json.loads(args["model_config"])
        path = Path(args["model_repository"]) / args["model_version"] / "model.onnx"
        threads = (config.get("parameters", {}).get("intra_op_thread_count") or {}).get("string_value")
        self._session = create_session(path, threads=int(threads) if threads else None)
        meta = parse_meta(self._session.get_modelmeta().custom_metadata_map.get(METADATA_KEY), source=f"model {path}")
        self._shapes = {i.name: list(i.shape) for i in self._session.get_inputs()}
        check_interface(self._shapes, [o.name for o in self._session.get_outputs()], meta, f"model {path}")
        self._context = f"model {config.get('name', path.parent.parent.name)}"

    def execute(self, requests: list[Any]) -> list[Any]:
        """Run the requests' frames as one batch; a request that does not fit the file gets its error alone.

        A request with a missing input, a wrong type or shape, or inputs whose batches differ is answered with an
        error naming the tensor; the others run. A failing run answers every accepted request with its error.

        Args:
            requests (list[Any]): Triton's ``InferenceRequest`` objects.

        Returns:
            list: One ``InferenceResponse`` per request, in order.
        """
        pb = self._pb
        responses: list[Any] = [None] * len(requests)
        accepted: list[tuple[int, dict[str, np.ndarray], int]] = []
        for i, request in enumerate(requests):
            arrays = {}
            for name in self._shapes:
                tensor = pb.get_input_tensor_by_name(request, name)
                arrays[name] = None if tensor is None else np.from_dlpack(tensor)
            try:
                accepted.append((i, arrays, check_request(arrays, self._shapes)))  # type: ignore[arg-type]
            except FrameError as exc:
                responses[i] = pb.InferenceResponse(error=pb.TritonError(f"{self._context}: {exc}"))
        if accepted:
            feeds = {name: np.concatenate([a[name] for _, a, _ in accepted]) for name in self._shapes}
            try:
                with map_ort_errors(self._context), flushed_denormals():
                    outputs = self._session.run(list(OUTPUTS), feeds)
            except FisheyeInferError as exc:
                for i, _, _ in accepted:
                    responses[i] = pb.InferenceResponse(error=pb.TritonError(str(exc)))
                return responses
            start = 0
            for i, _, batch in accepted:
                tensors = [_output_tensor(pb, n, o[start : start + batch]) for n, o in zip(OUTPUTS, outputs)]
                responses[i] = pb.InferenceResponse(output_tensors=tensors)
                start += batch
        return responses

    def finalize(self) -> None:
        """Release the session when Triton unloads the model."""
        self._session = None
