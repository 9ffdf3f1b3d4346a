"""Dependencies as ``Annotated`` aliases: ``ServiceDep``, ``SettingsDep``, ``DetectorDep``, ``ApiKeyDep``.

    @router.get("/model")
    async def model(detector: DetectorDep, _: ApiKeyDep) -> ModelInfo: ...

The API key is compared in constant time; health endpoints do not depend on it.
"""

from __future__ import annotations

import secrets
from typing import Annotated

from fastapi import Depends, Security
from fastapi.security import APIKeyHeader
from starlette.requests import HTTPConnection

from fisheye_infer.runtime.detector import Detector
from fisheye_infer.service.errors import Unauthorized, Unavailable
from fisheye_infer.service.settings import ServiceSettings
from fisheye_infer.service.state import Service

__all__ = ["API_KEY_HEADER", "ServiceDep", "SettingsDep", "DetectorDep", "ApiKeyDep", "get_service", "check_api_key"]

API_KEY_HEADER = "X-API-Key"
_api_key_header = APIKeyHeader(
    name=API_KEY_HEADER, auto_error=False, description="required when the service was started with an api_key"
)


def get_service(connection: HTTPConnection) -> Service:
    return connection.app.state.service


ServiceDep = Annotated[Service, Depends(get_service)]


def get_settings(service: ServiceDep) -> ServiceSettings:
    return service.settings


SettingsDep = Annotated[ServiceSettings, Depends(get_settings)]


def get_detector(service: ServiceDep) -> Detector:
    if service.detector is None:
        raise Unavailable("model: not loaded yet", field="model", retry_after=service.settings.retry_after_s)
    return service.detector


DetectorDep = Annotated[Detector, Depends(get_detector)]


def check_api_key(settings: ServiceSettings, given: str | None) -> None:
    """Raise ``Unauthorized`` unless no key is configured or ``given`` matches it."""
    if settings.api_key is None:
        return
    if given is None:
        raise Unauthorized(f"{API_KEY_HEADER}: header missing; this service requires an API key", field=API_KEY_HEADER)
    if not secrets.compare_digest(given.encode(), settings.api_key.get_secret_value().encode()):
        raise Unauthorized(f"{API_KEY_HEADER}: the key given does not match", field=API_KEY_HEADER)


def require_api_key(settings: SettingsDep, key: Annotated[str | None, Security(_api_key_header)] = None) -> None:
    check_api_key(settings, key)


ApiKeyDep = Annotated[None, Depends(require_api_key)]
