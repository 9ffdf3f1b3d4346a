"""The service on Ray Serve: the same FastAPI app on N replicas, one Detector each, batched with ``@serve.batch``.

    fisheye-infer serve model.onnx --ray --replicas 2 --cpus-per-replica 1 [--max-batch-size 4] [--batch-wait-ms 10]
    serve run fisheye_infer.service.ray_serve:app_builder model_path=/abs/model.onnx replicas=2

Each replica is a ``FisheyeReplica``: ``serve.ingress`` wraps the app ``create_app`` builds, so
the routes, limits, refusals, ``/healthz``, ``/readyz``, ``/metrics`` and ``/model`` are those of
``fisheye-infer serve``. Only the model call differs. The app's inference queue hands each
request's frames to ``BatchedDetector``, which submits them one by one to the replica's
``@serve.batch`` method; frames of concurrent callers that arrive within ``batch_wait_ms`` run
as one ``detect_batch`` of up to ``max_batch_size`` frames. How many ran together is counted
in ``/metrics`` as ``fisheye_serve_batch_frames`` (the answer's ``batch_size`` counts the frames
of the request itself). Ray's health check asks the replica whether its Detector is loaded and
warmed, as ``/readyz`` does.

The model path must exist on every node that runs a replica. ONNX Runtime gets
``cpus_per_replica`` intra-op threads per replica (unless ``threads`` is set), so replicas
sharing a machine do not oversubscribe its cores.
"""

from __future__ import annotations

import asyncio
from collections.abc import Callable, Coroutine, Iterable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, cast

from prometheus_client import Histogram
from ray import serve
from ray.serve import Application, Deployment

from fisheye_infer.runtime.detections import Detections
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.runtime.preprocess import Frame
from fisheye_infer.service.app import create_app
from fisheye_infer.service.settings import ServiceSettings

__all__ = ["RayServeOptions", "BatchedDetector", "FisheyeReplica", "build_app", "app_builder"]


@dataclass(frozen=True)
class RayServeOptions:
    """Replicas and batching of the Ray Serve deployment ([`build_app`][fisheye_infer.service.ray_serve.build_app]).

    Attributes:
        replicas (int): Copies of the application, each with its own Detector; at least 1.
        cpus_per_replica (float): CPUs Ray reserves per replica; also its ONNX Runtime threads (rounded down, at
            least 1) unless the settings name ``threads``.
        max_batch_size (int): Most frames in one ``@serve.batch`` run, 1 to 16.
        batch_wait_ms (float): How long the first frame of a batch waits for others, 0 to 1000 ms.

    Raises:
        ValueError: A value is out of its range.
    """

    replicas: int = 1
    cpus_per_replica: float = 1.0
    max_batch_size: int = 4
    batch_wait_ms: float = 10.0

    def __post_init__(self) -> None:
        if self.replicas < 1:
            raise ValueError(f"replicas: expected at least 1, got {self.replicas}")
        if not self.cpus_per_replica > 0:
            raise ValueError(f"cpus_per_replica: expected a positive number, got {self.cpus_per_replica}")
        if not 1 <= self.max_batch_size <= 16:
            raise ValueError(f"max_batch_size: expected 1..16, got {self.max_batch_size}")
        if not 0 <= self.batch_wait_ms <= 1000:
            raise ValueError(f"batch_wait_ms: expected 0..1000, got {self.batch_wait_ms}")

    def replica_settings(self, settings: ServiceSettings) -> ServiceSettings:
        """The application's settings inside a replica.

        One queue worker per frame a batch can hold, so that that many requests can wait in ``@serve.batch``
        together; the queue's own micro-batching off; ``threads`` from ``cpus_per_replica`` unless set.

        Args:
            settings (ServiceSettings): The service's settings.

        Returns:
            ServiceSettings: A copy with ``workers``, ``microbatch_max_size`` and ``threads`` set for a replica.
        """
        threads = settings.threads or max(1, int(self.cpus_per_replica))
        return settings.model_copy(
            update={"workers": max(settings.workers, self.max_batch_size), "microbatch_max_size": 1, "threads": threads}
        )


class BatchedDetector:
    """What the app sees as its Detector inside a replica: ``detect_batch`` goes through ``@serve.batch``.

    The app's queue workers call ``detect_batch`` from their threads; each frame is submitted to
    the replica's event loop, where the batch method collects frames from all callers.
    """

    def __init__(
        self,
        detector: Detector,
        submit: Callable[[Frame], Coroutine[Any, Any, Detections]],
        loop: asyncio.AbstractEventLoop,
    ) -> None:
        self._detector = detector
        self._submit = submit
        self._loop = loop
        self.info = detector.info
        self.score_threshold = detector.score_threshold
        self.nms = detector.nms

    @property
    def ready(self) -> bool:
        return self._detector.ready

    def warmup(self) -> None:
        self._detector.warmup()

    def run_arrays(self, images: Any, valid: Any) -> list[Any]:
        return self._detector.run_arrays(images, valid)

    def map_images(self, fn: Callable[[Any], Any], items: Iterable[Any]) -> Iterator[Any]:
        return self._detector.map_images(fn, items)

    def detect_batch(self, frames: Sequence[Frame], **options: Any) -> list[Detections]:
        if options:
            raise TypeError(f"per-call options {sorted(options)} are applied by the service after the run")
        futures = [asyncio.run_coroutine_threadsafe(self._submit(frame), self._loop) for frame in frames]
        return [f.result() for f in futures]


@serve.deployment(name="fisheye-infer")
@serve.ingress()
class FisheyeReplica:
    """One replica: a Detector, the app around it, and the batch method. See the module docstring."""

    def __init__(self, settings: ServiceSettings, options: RayServeOptions) -> None:
        self.settings = options.replica_settings(settings)
        self.detector = Detector(
            self.settings.model_path,
            threads=self.settings.threads,
            providers=self.settings.session_providers,
            spin=self.settings.spin,
            warmup=self.settings.warmup,
            decode_threads=self.settings.threads,
        )  # the replica's CPUs, no more
        # serve.batch's wrapper has these setters; ray types the decorated method as the plain function
        self._batched.set_max_batch_size(options.max_batch_size)  # type: ignore[attr-defined]
        self._batched.set_batch_wait_timeout_s(options.batch_wait_ms / 1e3)  # type: ignore[attr-defined]
        self._batch_frames: Histogram | None = None

    async def __serve_build_asgi_app__(self) -> Any:
        app = create_app(self.settings, BatchedDetector(self.detector, self._batched, asyncio.get_running_loop()))  # type: ignore[arg-type]
        self._batch_frames = Histogram(
            "fisheye_serve_batch_frames",
            "frames per @serve.batch run in this replica",
            buckets=(1, 2, 3, 4, 6, 8, 12, 16),
            registry=app.state.service.metrics.registry,
        )
        return app

    @serve.batch(max_batch_size=4, batch_wait_timeout_s=0.01)
    async def _batched(self, frames: list[Frame]) -> list[Detections]:
        if self._batch_frames is not None:
            self._batch_frames.observe(len(frames))
        return await asyncio.get_running_loop().run_in_executor(None, self.detector.detect_batch, frames)

    def check_health(self) -> None:
        """Ray restarts a replica whose Detector is not loaded and warmed (what ``/readyz`` reports)."""
        if not self.detector.ready:
            raise RuntimeError(f"model {self.settings.model_path}: not loaded and warmed")


def build_app(settings: ServiceSettings, options: RayServeOptions | None = None) -> Application:
    """The Ray Serve application: the service's FastAPI application on ``options.replicas`` replicas.

    Each replica holds one Detector and serves the routes of [`create_app`][fisheye_infer.service.app.create_app];
    frames of concurrent requests are batched with ``@serve.batch``. ``model_path`` is made absolute and must
    exist on every node that runs a replica. Ray's health check restarts a replica whose Detector is not loaded.

    Args:
        settings (ServiceSettings): The service's settings
            ([`ServiceSettings`][fisheye_infer.service.settings.ServiceSettings]).
        options (RayServeOptions | None): Replicas and batching; None for ``RayServeOptions()``.

    Returns:
        Application: The bound deployment, for ``serve.run``.

    Examples:
        ```python
        from ray import serve

        from fisheye_infer.service.ray_serve import RayServeOptions, build_app
        from fisheye_infer.service.settings import ServiceSettings

        serve.run(build_app(ServiceSettings(model_path="model.onnx"), RayServeOptions(replicas=2, max_batch_size=4)))
        ```
    """
    options = options or RayServeOptions()
    settings = settings.model_copy(
        update={"model_path": settings.model_path.resolve()}
    )  # replicas do not share the caller's cwd
    # Ray routes at most this many requests to a replica at once; the app's own queue refuses
    # beyond queue_size (503), as the plain service does. Two more leave room for health probes.
    ongoing = options.replica_settings(settings).workers + settings.queue_size + 2
    # serve.deployment made the class a Deployment; mypy keeps a decorated class's own type
    deployment = cast(Deployment, FisheyeReplica).options(
        num_replicas=options.replicas,
        ray_actor_options={"num_cpus": options.cpus_per_replica},
        max_ongoing_requests=ongoing,
        graceful_shutdown_timeout_s=settings.drain_timeout_s,
    )
    return deployment.bind(settings, options)


def app_builder(args: dict[str, str]) -> Application:
    """The application builder for ``serve run fisheye_infer.service.ray_serve:app_builder model_path=... replicas=2``.

    The settings other than ``model_path`` come from the ``FISHEYE_*`` environment variables, as for
    ``fisheye-infer serve``.

    Args:
        args (dict[str, str]): ``serve run``'s ``key=value`` arguments: ``model_path`` (else ``FISHEYE_MODEL_PATH``)
            and any of ``replicas``, ``cpus_per_replica``, ``max_batch_size``, ``batch_wait_ms``.

    Returns:
        Application: What [`build_app`][fisheye_infer.service.ray_serve.build_app] returns for them.

    Raises:
        ValueError: An argument is unknown, or a value does not parse or is out of range.
        pydantic.ValidationError: The settings are refused (see ``ServiceSettings``).
    """
    fields = {"replicas": int, "cpus_per_replica": float, "max_batch_size": int, "batch_wait_ms": float}
    unknown = sorted(set(args) - set(fields) - {"model_path"})
    if unknown:
        raise ValueError(f"arguments: unknown {unknown}; expected model_path and any of {', '.join(fields)}")
    settings = ServiceSettings(model_path=args["model_path"]) if "model_path" in args else ServiceSettings()
    return build_app(settings, RayServeOptions(**{k: cast(args[k]) for k, cast in fields.items() if k in args}))
