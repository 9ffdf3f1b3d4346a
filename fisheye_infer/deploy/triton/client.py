"""``TritonDetector``: the same ``detect()`` as ``Detector``, with the graph run by a Triton server.

    detector = TritonDetector("127.0.0.1:8000", "fisheye_bevdet")      # or "https://host:8443"
    detector = TritonDetector("127.0.0.1:8001", "fisheye_bevdet", protocol="grpc")
    dets = detector.detect({"fisheye_camera_front": "front.png", ...})  # decoded, checked, stacked here

Only the graph run crosses the network: decoding, validation, stacking and post-processing
are ``FrameDetector``'s, the code ``Detector`` runs, so both return the same boxes for the same
file. The model's metadata (classes, cameras, image size, rig) is read from the served model's
configuration (the ``fisheye_infer`` parameter that ``fisheye-infer triton`` writes), and the
served inputs and outputs are checked against it. Tensors travel as binary data: KServe v2's binary
tensor extension over HTTP, raw tensor contents over gRPC; batches larger than the server's
``max_batch_size`` are split.

tritonclient's clients are not shared between threads here: each thread gets its own; one
``TritonDetector`` may be shared by threads like a ``Detector``. Server and connection
failures are translated here, at one boundary: ``ArtifactError`` when the model is missing,
not ready or not a fisheye-infer model, ``InferenceError`` when a run fails.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from typing import Any

import numpy as np

from fisheye_infer.errors import ArtifactError, InferenceError, OptionError
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, METADATA_KEY, OUTPUTS, parse_meta
from fisheye_infer.runtime.detector import FrameDetector, check_interface, describe
from fisheye_infer.runtime.nms import NmsConfig

__all__ = ["TritonDetector", "NEEDS_TRITON", "PROTOCOLS"]

NEEDS_TRITON = "TritonDetector needs the triton extra: pip install 'fisheye-infer[triton]'"
PROTOCOLS = ("http", "grpc")


def _import_client(protocol: str) -> Any:
    try:
        if protocol == "grpc":
            import tritonclient.grpc as client
        else:
            import tritonclient.http as client
    except ImportError as exc:
        raise ImportError(f"{NEEDS_TRITON} ({exc})") from exc
    return client


@contextmanager
def _mapped(context: str, error: type[Exception] = InferenceError) -> Iterator[None]:
    """tritonclient's and the socket layer's exceptions -> the fisheye-infer tree."""
    from tritonclient.utils import InferenceServerException

    try:
        yield
    except InferenceServerException as exc:
        code = str(exc.status() or "")
        grpc = code.startswith("StatusCode.")
        status = f" (gRPC {code.removeprefix('StatusCode.')})" if grpc else code and f" (HTTP {code})"
        raise error(f"{context}: the server answered{status}: {exc.message()}") from exc
    except OSError as exc:  # refused, reset, timed out: geventhttpclient raises socket errors
        raise error(f"{context}: cannot reach the server ({exc})") from exc


class TritonDetector(FrameDetector):
    """[`Detector`][fisheye_infer.runtime.detector.Detector]'s ``detect()``, with the graph run by a Triton server.

    Only the graph run crosses the network: decoding, checks, stacking and post-processing run here, as in
    ``Detector``, so both return the same boxes for the same file. The model's metadata (classes, cameras, image
    size, rig) is read from the served model's configuration (the ``fisheye_infer`` parameter that
    [`write_repository`][fisheye_infer.deploy.triton.repository.write_repository] writes), and the served inputs and
    outputs are checked against it. Batches larger than the server's ``max_batch_size`` are split. One instance may
    be shared by threads (each thread gets its own tritonclient client). A failed run raises ``InferenceError``
    from ``detect``.

    Args:
        url (str): The server's address, ``host:port`` (``https://host:port`` for TLS; an ``http://`` prefix is
            dropped).
        model (str): The served model's name.
        protocol (str): ``http`` (KServe v2 over HTTP, the server's HTTP port) or ``grpc`` (the server's gRPC port).
        version (str): The model version; ``''`` for the server's choice.
        headers (Mapping[str, str] | None): Headers sent with every request (authentication); None for none.
        timeout_s (float): Connection and request timeout, in seconds.
        score_threshold (float | None): Keep boxes scoring at least this, in [0, 1]; None keeps every box.
        nms (NmsConfig | None): NMS after the graph
            ([`NmsConfig`][fisheye_infer.runtime.nms.NmsConfig]); None for none.
        warmup (bool): Run once on a black frame at construction.

    Raises:
        ImportError: tritonclient is not installed (the ``[triton]`` extra).
        ArtifactError: The server cannot be reached, or the model is missing, not ready, or not a fisheye-infer
            model.
        OptionError: ``protocol`` is neither ``http`` nor ``grpc``.

    Examples:
        ```python
        from fisheye_infer.deploy.triton.client import TritonDetector

        detector = TritonDetector("127.0.0.1:8000", "fisheye_bevdet", score_threshold=0.3)
        dets = detector.detect({"fisheye_camera_front": "front.png", "fisheye_camera_left": "left.png",
                                "fisheye_camera_right": "right.png", "fisheye_camera_rear": "rear.png"})
        grpc = TritonDetector("127.0.0.1:8001", "fisheye_bevdet", protocol="grpc")
        ```
    """

    def __init__(
        self,
        url: str,
        model: str,
        *,
        protocol: str = "http",
        version: str = "",
        headers: Mapping[str, str] | None = None,
        timeout_s: float = 60.0,
        score_threshold: float | None = None,
        nms: NmsConfig | None = None,
        warmup: bool = False,
    ) -> None:
        if protocol not in PROTOCOLS:
            raise OptionError(f"protocol: expected one of {', '.join(PROTOCOLS)}, got {protocol!r}")
        self.protocol = protocol
        self._api = _import_client(protocol)
        self.ssl = url.startswith("https://")
        self.url = url.removeprefix("https://").removeprefix("http://").rstrip("/")
        self.model, self.version = model, version
        self.headers = dict(headers or {})
        self.timeout_s = timeout_s
        self._local = threading.local()
        where = f"model '{model}' at {self.url}"
        with _mapped(where, ArtifactError):
            # raises with the server's reason
            metadata = self._client().get_model_metadata(model, version, **self._json)
            config = self._client().get_model_config(model, version, **self._json)
            config = config.get("config", config)  # gRPC wraps the configuration in a response
            if not self._client().is_model_ready(model, version, headers=self.headers):
                raise ArtifactError(f"{where}: the server does not report it ready")
        document = (config.get("parameters", {}).get(METADATA_KEY) or {}).get("string_value")
        meta = parse_meta(document, source=where)
        self.max_batch_size = int(config.get("max_batch_size", 0))
        batch = [-1] if self.max_batch_size > 0 else []
        inputs = {i["name"]: [int(d) for d in i["shape"]] for i in metadata.get("inputs", [])}
        if self.max_batch_size > 0:  # Triton reports the batch axis of batched models as -1
            inputs = {k: v if v[:1] == [-1] else batch + v for k, v in inputs.items()}
        check_interface(inputs, [o["name"] for o in metadata.get("outputs", [])], meta, where)
        super().__init__(describe(meta, (f"triton:{self.url}/{model}",)), score_threshold=score_threshold, nms=nms)
        if warmup:
            self.warmup()
        self.ready = True

    @property
    def _json(self) -> dict[str, Any]:
        """Keyword arguments of the metadata calls: the headers, and JSON answers over gRPC."""
        return {"headers": self.headers, **({"as_json": True} if self.protocol == "grpc" else {})}

    def _client(self) -> Any:
        client = getattr(self._local, "client", None)
        if client is None:
            timeouts = (
                {"connection_timeout": self.timeout_s, "network_timeout": self.timeout_s}
                if self.protocol == "http"
                else {}
            )
            client = self._api.InferenceServerClient(self.url, ssl=self.ssl, **timeouts)
            self._local.client = client
        return client

    def _infer(self, images: np.ndarray, valid: np.ndarray) -> list[np.ndarray]:
        api = self._api
        binary = {"binary_data": True} if self.protocol == "http" else {}
        inputs = [
            api.InferInput(INPUT_IMAGES, list(images.shape), "UINT8"),
            api.InferInput(INPUT_CAMERA_VALID, list(valid.shape), "BOOL"),
        ]
        inputs[0].set_data_from_numpy(np.ascontiguousarray(images, np.uint8), **binary)
        inputs[1].set_data_from_numpy(np.ascontiguousarray(valid, bool), **binary)
        outputs = [api.InferRequestedOutput(name, **binary) for name in OUTPUTS]
        timeout = {"client_timeout": self.timeout_s} if self.protocol == "grpc" else {}
        with _mapped(f"model '{self.model}' at {self.url}"):
            result = self._client().infer(
                self.model, inputs, model_version=self.version, outputs=outputs, headers=self.headers, **timeout
            )
            arrays = [result.as_numpy(name) for name in OUTPUTS]
        missing = [name for name, a in zip(OUTPUTS, arrays) if a is None]
        if missing:
            raise InferenceError(f"model '{self.model}' at {self.url}: the answer lacks output(s) {', '.join(missing)}")
        return arrays

    def _run(self, images: np.ndarray, valid: np.ndarray) -> list[np.ndarray]:
        step = self.max_batch_size or len(images)  # max_batch_size 0: the batch axis is the model's own
        parts = [self._infer(images[i : i + step], valid[i : i + step]) for i in range(0, len(images), step)]
        return [np.concatenate([p[k] for p in parts]) for k in range(len(OUTPUTS))]
