"""X-API-Key: required everywhere except the health endpoints (and, with docs_public, the docs); compared, never echoed."""

from __future__ import annotations

import json

import httpx
import pytest
from service_live import API_KEY, ORIGIN, LiveServer, multipart
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from fisheye_infer.service.protocol import encode_frame


@pytest.mark.parametrize(
    "method, path, key, status",
    [
        ("GET", "/healthz", None, 200),  # health stays open
        ("GET", "/readyz", None, 200),
        ("GET", "/model", None, 401),  # no key
        ("GET", "/model", "wrong-key-of-some-length", 401),  # wrong key
        ("GET", "/model", API_KEY, 200),
        ("GET", "/metrics", None, 401),  # metrics_public=False on this server
        ("GET", "/metrics", API_KEY, 200),
        ("POST", "/detect", None, 401),
        ("POST", "/detect/batch", "", 401),
        ("GET", "/openapi.json", None, 401),  # the schema names cameras, classes and limits
        ("GET", "/openapi.json", API_KEY, 200),
        ("GET", "/docs", None, 401),
        ("GET", "/docs", API_KEY, 200),
        ("GET", "/redoc", API_KEY, 404),  # not served behind a key
    ],
)
def test_key_is_required_except_for_health(
    keyed_server: LiveServer, method: str, path: str, key: str | None, status: int
) -> None:
    headers = {} if key is None else {"X-API-Key": key}
    response = httpx.request(method, keyed_server.url + path, headers=headers, timeout=20)
    assert response.status_code == status, response.text
    if status == 401:
        assert response.json()["field"] == "X-API-Key" and API_KEY not in response.text


def test_detect_with_the_key(keyed_server: LiveServer, images: dict[str, bytes]) -> None:
    response = httpx.post(
        keyed_server.url + "/detect", files=multipart(images), headers={"X-API-Key": API_KEY}, timeout=20
    )
    assert response.status_code == 200


def test_stream_needs_the_key(keyed_server: LiveServer, images: dict[str, bytes]) -> None:
    with connect(keyed_server.ws_url) as ws:
        refused = json.loads(ws.recv(timeout=5))
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=5)
    assert refused["status"] == 401 and closed.value.rcvd.code == 1008
    with connect(keyed_server.ws_url, additional_headers={"X-API-Key": API_KEY}) as ws:
        ws.send(encode_frame(5, images))
        assert json.loads(ws.recv(timeout=10))["frame_id"] == 5


@pytest.mark.parametrize("origin, allowed", [(ORIGIN, True), ("https://elsewhere.example", False)])
def test_cors_preflight_allows_the_configured_origin_and_the_key_header(
    keyed_server: LiveServer, origin: str, allowed: bool
) -> None:
    headers = {"Origin": origin, "Access-Control-Request-Method": "POST", "Access-Control-Request-Headers": "x-api-key"}
    response = httpx.options(keyed_server.url + "/detect", headers=headers, timeout=10)
    assert (response.status_code == 200) is allowed
    assert (response.headers.get("access-control-allow-origin") == origin) is allowed


def test_docs_public_serves_the_schema_without_the_key(small_model, detector) -> None:
    from service_live import serve, settings_for

    for live in serve(settings_for(small_model, api_key=API_KEY, docs_public=True), detector):
        assert httpx.get(live.url + "/openapi.json", timeout=20).status_code == 200
        assert httpx.get(live.url + "/docs", timeout=20).status_code == 200
        assert httpx.get(live.url + "/model", timeout=20).status_code == 401
