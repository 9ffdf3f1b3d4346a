"""Clients that stall, trickle, smuggle or send too much, against the real server on 127.0.0.1.

Raw sockets where the client's timing or framing is the point, every one with a timeout; the
short deadlines live on ``strict_server`` so that no test waits long.
"""

from __future__ import annotations

import contextlib
import http.client
import json
import select
import socket
import time
import urllib.error
import urllib.request
from collections.abc import Iterator

import httpx
import pytest
from service_live import LiveServer, multipart, serve, settings_for

from fisheye_infer.runtime.detector import Detector

HEADER_TIMEOUT_S, BODY_TIMEOUT_S, MAX_CONNECTIONS = 1.0, 1.5, 6


@pytest.fixture(scope="module")
def strict_server(small_model, detector: Detector) -> Iterator[LiveServer]:
    """Short deadlines for headers and bodies, and few connections."""
    yield from serve(
        settings_for(
            small_model,
            header_timeout_s=HEADER_TIMEOUT_S,
            body_timeout_s=BODY_TIMEOUT_S,
            max_connections=MAX_CONNECTIONS,
        ),
        detector,
    )


def stalled_upload(port: int) -> socket.socket:
    """POST /detect announcing a 1 MB multipart body, of which ~100 bytes are sent; then nothing."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=10)
    sock.sendall(
        b"POST /detect HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: 1000000\r\n"
        b"Content-Type: multipart/form-data; boundary=bnd\r\n\r\n--bnd\r\n" + b"x" * 93
    )
    return sock


def trickle(sock: socket.socket, data: bytes, pause: float = 0.2) -> None:
    """Send ``data`` a byte at a time until the server answers (or the data runs out)."""
    for byte in data:
        if select.select([sock], [], [], pause)[0]:
            return
        try:
            sock.sendall(bytes([byte]))
        except (BrokenPipeError, ConnectionResetError):
            return


def read_answer(sock: socket.socket) -> tuple[http.client.HTTPResponse, dict]:
    answer = http.client.HTTPResponse(sock)
    answer.begin()
    return answer, json.loads(answer.read())


def closed(sock: socket.socket, within: float = 5.0) -> bool:
    """True once the server has closed the connection (EOF or reset) within ``within`` seconds."""
    sock.settimeout(within)
    try:
        while sock.recv(65536):
            pass
    except ConnectionResetError:
        return True
    except TimeoutError:
        return False
    return True


def test_stalled_uploads_hold_no_queue_place(server: LiveServer, images: dict[str, bytes]) -> None:
    """Nine stalled uploads (the queue holds 2) leave valid requests served at once."""
    gone_before = server.metric("fisheye_requests_total", endpoint="/detect", status="499")
    with contextlib.ExitStack() as stack:
        held = [stack.enter_context(stalled_upload(server.port)) for _ in range(9)]
        started = time.monotonic()
        response = httpx.post(server.url + "/detect", files=multipart(images), timeout=10)
        assert response.status_code == 200 and time.monotonic() - started < 10
        assert server.metric("fisheye_queue_depth") == 0
        for sock in held:  # still open and unanswered: their body deadline (30 s) has not passed
            assert not select.select([sock], [], [], 0)[0]
    # the stalled clients left: each is counted once, as a client that closed (499)
    assert (
        server.wait_metric("fisheye_requests_total", lambda v: v >= gone_before + 9, endpoint="/detect", status="499")
        == gone_before + 9
    )


def test_slow_body_gets_408_and_its_connection_closed(strict_server: LiveServer, images: dict[str, bytes]) -> None:
    request = httpx.Request("POST", strict_server.url, files=multipart(images))
    body = request.read()
    with socket.create_connection(("127.0.0.1", strict_server.port), timeout=10) as sock:
        sock.sendall(
            f"POST /detect HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Length: {len(body)}\r\n"
            f"Content-Type: {request.headers['content-type']}\r\n\r\n".encode()
        )
        started = time.monotonic()
        trickle(sock, body[:200])  # 5 bytes a second
        answer, error = read_answer(sock)
        assert answer.status == 408 and error["field"] == "body" and "body_timeout_s=1.5" in error["error"]
        assert answer.getheader("connection") == "close" and time.monotonic() - started < BODY_TIMEOUT_S + 5
        assert closed(sock)


def test_slow_headers_get_408_and_the_connection_closed(strict_server: LiveServer) -> None:
    with socket.create_connection(("127.0.0.1", strict_server.port), timeout=10) as sock:
        started = time.monotonic()
        trickle(sock, b"GET /model HTTP/1.1\r\nHost: 127.0.0.1\r\nUser-Agent: " + b"s" * 60 + b"\r\n\r\n")
        answer, error = read_answer(sock)
        assert answer.status == 408 and error == {
            "error": "headers: not received within header_timeout_s=1 s",
            "status": 408,
            "type": "RequestTimeout",
            "field": "headers",
        }
        assert time.monotonic() - started < HEADER_TIMEOUT_S + 5
        assert closed(sock)


def test_keep_alive_requests_each_get_the_header_deadline(strict_server: LiveServer) -> None:
    """A quick first request, then the next one's headers trickle in on the same connection."""
    with socket.create_connection(("127.0.0.1", strict_server.port), timeout=10) as sock:
        sock.sendall(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n")
        assert read_answer(sock)[0].status == 200
        trickle(sock, b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nUser-Agent: " + b"s" * 60 + b"\r\n\r\n")
        assert read_answer(sock)[0].status == 408


def test_connections_are_bounded(small_model, detector: Detector, images: dict[str, bytes]) -> None:
    """A server of its own: the count must not include other tests' connections."""
    for live in serve(settings_for(small_model, max_connections=MAX_CONNECTIONS), detector):
        with contextlib.ExitStack() as stack:
            for _ in range(MAX_CONNECTIONS - 1):  # uvicorn counts this request's own connection too
                stack.enter_context(stalled_upload(live.port))
                time.sleep(0.1)  # each request seen before the next connection opens
            refused = httpx.post(live.url + "/detect", files=multipart(images), timeout=10)
            assert refused.status_code == 503  # uvicorn's answer beyond limit_concurrency
        deadline = time.monotonic() + 10
        while (status := httpx.post(live.url + "/detect", files=multipart(images), timeout=10).status_code) == 503:
            assert time.monotonic() < deadline  # the stalled clients left: room again
            time.sleep(0.05)
        assert status == 200


def test_content_length_with_transfer_encoding_is_refused_and_the_connection_closed(server: LiveServer) -> None:
    """The smuggled second request (hidden in the chunked body) is never answered."""
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as sock:
        sock.sendall(
            b"POST /detect HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nContent-Length: 4\r\n"
            b"Transfer-Encoding: chunked\r\n\r\n0\r\n\r\nGET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
        )
        answer, error = read_answer(sock)
        assert answer.status == 400 and error["field"] == "Transfer-Encoding" and "RFC 9112" in error["error"]
        sock.settimeout(5)
        rest = b""
        with contextlib.suppress(ConnectionResetError):
            while chunk := sock.recv(65536):
                rest += chunk
        assert b"HTTP/1.1" not in rest


def test_over_limit_body_is_answered_to_a_client_that_writes_it_all(server: LiveServer) -> None:
    """urllib writes the whole 40 MiB before reading (and asks to close): it reads the 413, not a reset."""
    request = urllib.request.Request(
        server.url + "/detect", data=bytes(40 << 20), headers={"Content-Type": "application/json"}
    )
    with pytest.raises(urllib.error.HTTPError) as refused:
        urllib.request.urlopen(request, timeout=30)
    assert refused.value.code == 413
    assert json.loads(refused.value.read())["field"] == "body"


def test_over_limit_body_with_expect_100_continue_is_refused_before_it_is_sent(server: LiveServer) -> None:
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as sock:
        sock.sendall(
            b"POST /detect HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            b"Content-Length: 41943040\r\nExpect: 100-continue\r\n\r\n"
        )
        answer, error = read_answer(sock)  # no "100 Continue" first: the client is told not to send
        assert answer.status == 413 and "41943040 bytes" in error["error"]
        assert closed(sock)


def _everything(sock: socket.socket, within: float = 5.0) -> bytes:
    """What the server sends until it closes the connection, bounded by ``within`` seconds."""
    data, deadline = b"", time.monotonic() + within
    while time.monotonic() < deadline and select.select([sock], [], [], deadline - time.monotonic())[0]:
        chunk = sock.recv(65536)
        if not chunk:
            return data
        data += chunk
    raise AssertionError(f"the connection was still open after {within} s; received {data[:200]!r}")


@pytest.mark.parametrize("path", ["/detect", "/v2/models/small/infer"])
def test_a_body_short_of_its_content_length_then_half_closed_gets_400(server: LiveServer, path: str) -> None:
    """uvicorn closed such a connection without an answer: the client is told its body is short."""
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as sock:
        sock.sendall(
            f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\n"
            "Content-Length: 100\r\n\r\n".encode()
            + b'{"images": {}}'
        )
        sock.shutdown(socket.SHUT_WR)
        head, _, body = _everything(sock).partition(b"\r\n\r\n")
    assert head.startswith(b"HTTP/1.1 400 ") and b"connection: close" in head.lower()
    assert json.loads(body) == {
        "error": "body: the client ended the connection before the 100 bytes its Content-Length declares had arrived",
        "status": 400,
        "type": "BadRequest",
        "field": "body",
    }


def test_bytes_after_a_short_body_are_refused_as_json_and_the_connection_closed(server: LiveServer) -> None:
    """A body shorter than its Content-Length on a kept-alive connection: the next request's bytes complete it
    (the app refuses that body), and what is left is not HTTP: the service's 400 (uvicorn's was the text
    "Invalid HTTP request received."), then the connection closes; no hang."""
    following = b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n"
    with socket.create_connection(("127.0.0.1", server.port), timeout=10) as sock:
        sock.sendall(
            b"POST /detect HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: application/json\r\nContent-Length: 40\r\n\r\n"
            + b'{"images": {}}'
            + following * 3
        )
        received = _everything(sock)
    first, second = received.split(b"HTTP/1.1 400 Bad Request\r\n")[1:]
    assert b"Invalid JSON" in first
    head, _, body = second.partition(b"\r\n\r\n")
    assert b"connection: close" in head.lower()
    answer = json.loads(body)
    assert answer["field"] == "request" and answer["error"].startswith("request: not a valid HTTP/1.1 request")
    assert "a body shorter than its Content-Length" in answer["error"]
