"""``ServiceSettings``: every knob of the service, typed, read from ``FISHEYE_*`` variables.

    FISHEYE_MODEL_PATH=/models/model.onnx FISHEYE_QUEUE_SIZE=16 fisheye-infer serve
    ServiceSettings(model_path="model.onnx", microbatch_max_size=4)      # in Python

| setting | default | what it bounds |
|---|---|---|
| ``model_path`` | required | the ONNX file written by ``fisheye-infer export`` |
| ``host`` / ``port`` | 127.0.0.1 / 8000 | where uvicorn listens; loopback unless told otherwise |
| ``threads`` | all cores | ONNX Runtime intra-op threads |
| ``spin`` | true | whether those threads spin for a while after a call (``false``: see below) |
| ``providers`` | CPU | execution providers in order (see below), or ``auto`` |
| ``workers`` | 1 | inference threads calling the Detector |
| ``queue_size`` | 8 | requests admitted and not yet running; beyond it: 503 + Retry-After |
| ``max_body_bytes`` | 32 MiB | request body and WebSocket message size (413 beyond) |
| ``max_batch_frames`` | 8 | frames in one /detect/batch request (422 beyond) |
| ``microbatch_max_size`` | 1 (off) | single-frame requests grouped into one run |
| ``microbatch_max_wait_ms`` | 5 | how long the first request of a group waits for others |
| ``request_timeout_s`` | 60 | no request waits longer for its result (504) |
| ``header_timeout_s`` | 10 | time for a request's headers to arrive (then 408 and the connection closed) |
| ``body_timeout_s`` | 30 | time for a request's body to arrive (then 408 and the connection closed) |
| ``max_connections`` | 64 | open connections and requests in progress (beyond: uvicorn answers 503) |
| ``drain_timeout_s`` | 30 | graceful shutdown: longest wait for in-flight work |
| ``api_key`` | none | when set, required as ``X-API-Key`` (health endpoints stay open) |
| ``docs_public`` | false | with an ``api_key``: serve ``/docs`` and ``/openapi.json`` without it |
| ``cors_origins`` | none | browser origins allowed to call the API |

With ``spin`` false the threads sleep at once after a call, leaving the cores to other processes.
``providers`` names them in order, as in ``CUDAExecutionProvider,CPUExecutionProvider``, or as a
JSON list for provider options.

Unsafe or contradictory combinations are refused when the settings are built, not at the
first request.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

from pydantic import Field, SecretStr, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

__all__ = ["ServiceSettings", "MIN_API_KEY_LENGTH"]

#: A provider by name, or with its options (``fisheye_infer.runtime.session.Provider``, as settings can hold it).
ProviderSetting = str | tuple[str, dict[str, str | int | float | bool]]

MIN_API_KEY_LENGTH = 16


class ServiceSettings(BaseSettings):
    """Every option and limit of the service, typed and checked, read from ``FISHEYE_*`` environment variables.

    Each field can be given as a keyword or as the environment variable ``FISHEYE_<FIELD>`` (``FISHEYE_QUEUE_SIZE``);
    keywords win. The settings are frozen; unsafe or contradictory combinations are refused here, not at the first
    request. ``cors_origins`` and ``providers`` also take comma-separated text.

    Attributes:
        model_path (Path): The ONNX file written by ``fisheye-infer export``; required.
        host (str): Where uvicorn listens; loopback (``127.0.0.1``) unless told otherwise.
        port (int): The port, 0 to 65535 (default 8000).
        threads (int | None): ONNX Runtime intra-op threads; None for all cores.
        spin (bool): Whether those threads spin for a while after a call; False makes them sleep at once, leaving
            the cores to other processes.
        providers (list[str | tuple[str, dict]]): ONNX Runtime execution providers in order of preference, by name
            (``CUDAExecutionProvider,CPUExecutionProvider``) or as ``(name, options)`` pairs (a JSON list in the
            environment), or ``["auto"]`` for the installed accelerated ones; empty for the CPU.
        workers (int): Inference threads calling the Detector, 1 to 16.
        queue_size (int): Requests admitted and not yet running; beyond it the answer is 503 with Retry-After.
        max_body_bytes (int): Largest request body and WebSocket message, in bytes (default 32 MiB; 413 beyond).
        max_batch_frames (int): Most frames in one ``/detect/batch`` request (422 beyond).
        microbatch_max_size (int): Single-frame requests grouped into one run; 1 turns micro-batching off. At most
            ``max_batch_frames``.
        microbatch_max_wait_ms (float): How long the first request of a group waits for others, 0 to 1000 ms.
        request_timeout_s (float): Longest wait of a request for its result, in seconds (504 beyond).
        header_timeout_s (float): Time for a request's headers to arrive, in seconds, at most 300 (then 408 and the
            connection is closed).
        body_timeout_s (float): Time for a request's body to arrive, in seconds (then 408 and the connection is
            closed).
        max_connections (int): Open connections and requests in progress, at least 2 (beyond: uvicorn answers 503).
        drain_timeout_s (float): Graceful shutdown: longest wait for in-flight work, in seconds; 0 stops at once.
        retry_after_s (int): The ``Retry-After`` value sent with 503 answers, in seconds.
        api_key (SecretStr | None): When set (at least 16 characters), required as the ``X-API-Key`` header; the
            health endpoints stay open. None for an open service.
        metrics_public (bool): Serve ``/metrics`` without the API key (for scrapers).
        docs_public (bool): With an ``api_key``: serve ``/docs`` and ``/openapi.json`` without it.
        cors_origins (list[str]): Browser origins allowed to call the API; empty for none. ``*`` is refused together
            with an ``api_key``.
        warmup (bool): Run the model once when the service starts, before it reports ready.

    Raises:
        pydantic.ValidationError: A value is out of range, ``model_path`` is missing, a provider is not offered by
            the installed onnxruntime, ``api_key`` is shorter than 16 characters, ``microbatch_max_size`` exceeds
            ``max_batch_frames``, or ``cors_origins`` holds ``*`` while an ``api_key`` is set.

    Examples:
        ```python
        from fisheye_infer.service.settings import ServiceSettings

        settings = ServiceSettings(model_path="model.onnx", queue_size=16, microbatch_max_size=4)
        # or from the environment: FISHEYE_MODEL_PATH=model.onnx FISHEYE_QUEUE_SIZE=16 fisheye-infer serve
        ```
    """

    model_config = SettingsConfigDict(env_prefix="FISHEYE_", extra="ignore", frozen=True)

    model_path: Path = Field(description="ONNX file written by fisheye-infer export")
    host: str = "127.0.0.1"
    port: int = Field(default=8000, ge=0, le=65535)
    threads: int | None = Field(default=None, ge=1, description="ONNX Runtime intra-op threads (default: all cores)")
    spin: bool = Field(
        default=True,
        description="ONNX Runtime's threads spin for a while after a call "
        "(false: they sleep at once, leaving the cores to other processes)",
    )
    providers: Annotated[list[ProviderSetting], NoDecode] = Field(
        default_factory=list,
        description="ONNX Runtime execution providers in order of preference (names, or (name, options) pairs), "
        "or ['auto'] for the installed accelerated ones (default: CPU)",
    )
    workers: int = Field(default=1, ge=1, le=16, description="inference threads calling the Detector")
    queue_size: int = Field(default=8, ge=1, description="requests admitted and not yet running")
    max_body_bytes: int = Field(default=32 * 1024 * 1024, ge=1024)
    max_batch_frames: int = Field(default=8, ge=1)
    microbatch_max_size: int = Field(default=1, ge=1, description="1 turns micro-batching off")
    microbatch_max_wait_ms: float = Field(default=5.0, ge=0.0, le=1000.0)
    request_timeout_s: float = Field(default=60.0, gt=0.0)
    header_timeout_s: float = Field(
        default=10.0, gt=0.0, le=300.0, description="time for a request's headers to arrive"
    )
    body_timeout_s: float = Field(default=30.0, gt=0.0, description="time for a request's body to arrive")
    max_connections: int = Field(default=64, ge=2, description="open connections and requests in progress")
    drain_timeout_s: float = Field(default=30.0, ge=0.0)
    retry_after_s: int = Field(default=1, ge=1, description="Retry-After sent with 503 answers")
    api_key: SecretStr | None = None
    metrics_public: bool = Field(default=True, description="serve /metrics without the API key (for scrapers)")
    docs_public: bool = Field(default=False, description="with an api_key: serve /docs and /openapi.json without it")
    cors_origins: Annotated[list[str], NoDecode] = Field(default_factory=list)
    warmup: bool = True

    @field_validator("cors_origins", mode="before")
    @classmethod
    def _split_list(cls, value: object) -> object:
        """Accept ``FISHEYE_CORS_ORIGINS=https://a,https://b`` as well as a JSON list."""
        if isinstance(value, str):
            if value.lstrip().startswith("["):
                return json.loads(value)
            return [v.strip() for v in value.split(",") if v.strip()]
        return value

    @field_validator("providers", mode="before")
    @classmethod
    def _parse_providers(cls, value: object) -> object:
        """``FISHEYE_PROVIDERS`` / ``--providers`` text as the command line reads it (``session.parse_providers``)."""
        if isinstance(value, str):
            from fisheye_infer.runtime.session import parse_providers

            parsed = parse_providers(value)
            return [parsed] if parsed == "auto" else parsed
        return value

    @field_validator("providers")
    @classmethod
    def _installed_providers(cls, value: list[ProviderSetting]) -> list[ProviderSetting]:
        """Refused here, before the model loads, when the installed onnxruntime does not offer one."""
        if value == ["auto"]:
            return value
        from fisheye_infer.runtime.session import resolve_providers

        resolve_providers(value)
        return value

    @property
    def session_providers(self) -> str | list[ProviderSetting] | None:
        """``providers`` as ``Detector``'s ``providers`` argument takes it: None (the CPU), ``"auto"`` or the list."""
        return None if not self.providers else "auto" if self.providers == ["auto"] else list(self.providers)

    @model_validator(mode="after")
    def _refuse_unsafe(self) -> ServiceSettings:
        if self.api_key is not None and len(self.api_key.get_secret_value()) < MIN_API_KEY_LENGTH:
            raise ValueError(
                f"api_key: expected at least {MIN_API_KEY_LENGTH} characters, got "
                f"{len(self.api_key.get_secret_value())}"
            )
        if self.microbatch_max_size > self.max_batch_frames:
            raise ValueError(
                f"microbatch_max_size: {self.microbatch_max_size} exceeds max_batch_frames {self.max_batch_frames}"
            )
        if "*" in self.cors_origins and self.api_key is not None:
            raise ValueError(
                "cors_origins: '*' together with an api_key would let any web page use a key it obtains; list the "
                "origins"
            )
        return self

    @property
    def microbatching(self) -> bool:
        """Whether single-frame requests are grouped (``microbatch_max_size`` above 1)."""
        return self.microbatch_max_size > 1
