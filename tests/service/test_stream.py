"""WebSocket /stream: answers carry frame ids, a fast sender gets the newest frames (latest wins),
memory stays at one pending frame per connection, and a vanished client leaves nothing behind."""

from __future__ import annotations

import contextlib
import json
import socket
import time
from typing import Any

import httpx
import pytest
from service_live import LiveServer, multipart
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import connect

from fisheye_infer.service.protocol import encode_frame
from fisheye_infer.service.schemas import StreamError, StreamResult

FRONT = "fisheye_camera_front"


def receive(ws: Any, timeout: float = 10.0) -> dict[str, Any]:
    return json.loads(ws.recv(timeout=timeout))


def test_one_frame_one_answer(server: LiveServer, images: dict[str, bytes]) -> None:
    with connect(server.ws_url + "?score_threshold=0.2") as ws:
        ws.send(encode_frame(7, images))
        answer = receive(ws)
    StreamResult.model_validate(answer)  # the documented message schema
    assert answer["kind"] == "result" and answer["frame_id"] == 7 and answer["dropped"] == []
    assert answer["cameras_used"] == list(images) and all(d["score"] >= 0.2 for d in answer["detections"])
    assert set(answer["timings_ms"]) == {"queue_wait", "decode", "preprocess", "inference", "postprocess"}


def test_fast_sender_gets_latest_frames_and_the_drops_named(server: LiveServer, images: dict[str, bytes]) -> None:
    sent = list(range(100, 140))
    dropped_before = server.metric("fisheye_stream_dropped_frames_total")
    answered: list[int] = []
    dropped: list[int] = []
    with connect(server.ws_url) as ws:
        for frame_id in sent:  # ~90 kB each, far faster than the model's ~90 ms per frame
            ws.send(encode_frame(frame_id, images))
        assert server.metric("fisheye_stream_pending_frames") <= 1  # one slot per connection, however fast the sender
        while sent[-1] not in answered:
            answer = receive(ws)
            assert answer["kind"] == "result", answer
            answered.append(answer["frame_id"])
            dropped += answer["dropped"]
    assert sorted(answered + dropped) == sent  # every frame answered or named as dropped, once
    assert answered == sorted(answered) and answered[-1] == sent[-1]  # newest frame always answered
    assert len(dropped) >= len(sent) // 2
    assert server.metric("fisheye_stream_dropped_frames_total") == dropped_before + len(dropped)


def test_bad_frame_content_is_refused_and_the_stream_goes_on(server: LiveServer, images: dict[str, bytes]) -> None:
    with connect(server.ws_url) as ws:
        ws.send(encode_frame(1, {**images, "fisheye_camera_roof": images[FRONT]}))
        refused = receive(ws)
        ws.send(encode_frame(2, {**images, FRONT: b"GIF89a" + bytes(32)}))
        unsupported = receive(ws)
        ws.send(encode_frame(3, images))
        ok = receive(ws)
    StreamError.model_validate(refused)
    assert (refused["kind"], refused["frame_id"], refused["status"], refused["field"]) == (
        "error",
        1,
        422,
        "fisheye_camera_roof",
    )
    assert (unsupported["frame_id"], unsupported["status"], unsupported["field"]) == (2, 415, FRONT)
    assert ok["kind"] == "result" and ok["frame_id"] == 3


@pytest.mark.parametrize(
    "message, code, words",
    [
        (b"FEYE", 1002, "header"),  # shorter than a header
        (b"JPEG" + bytes(20), 1002, "magic"),  # not this protocol
        (encode_frame(1, {FRONT: b"x"})[:4] + b"\x09" + encode_frame(1, {FRONT: b"x"})[5:], 1002, "version"),
        ("a text message", 1003, "binary"),
    ],
)
def test_unreadable_messages_close_with_a_reason(
    server: LiveServer, message: bytes | str, code: int, words: str
) -> None:
    with connect(server.ws_url) as ws:
        ws.send(message)
        answer = receive(ws)
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=5)
    assert answer["kind"] == "error" and words in answer["error"]
    assert closed.value.rcvd is not None and closed.value.rcvd.code == code


def test_bad_options_are_refused_at_connect(server: LiveServer) -> None:
    with connect(server.ws_url + "?classes=Dragon") as ws:
        answer = receive(ws)
        with pytest.raises(ConnectionClosed) as closed:
            ws.recv(timeout=5)
    assert answer["field"] == "classes" and closed.value.rcvd.code == 1008


def test_client_vanishing_mid_stream_leaves_the_server_clean(server: LiveServer, images: dict[str, bytes]) -> None:
    with connect(server.ws_url) as ws:
        for frame_id in range(10):
            ws.send(encode_frame(frame_id, images))
        assert server.wait_metric("fisheye_stream_connections", lambda v: v == 1) == 1
        ws.socket.shutdown(socket.SHUT_RDWR)  # gone without a close handshake, frames still in flight
        ws.socket.close()
    assert server.wait_metric("fisheye_stream_connections", lambda v: v == 0) == 0
    assert server.wait_metric("fisheye_inflight", lambda v: v == 0) == 0
    assert server.metric("fisheye_stream_pending_frames") == 0
    assert server.metric("fisheye_queue_depth") == 0
    assert server.service.streams == set()
    with httpx.Client(base_url=server.url, timeout=20) as client:
        assert client.get("/healthz").status_code == 200
        assert client.post("/detect", files=multipart(images)).status_code == 200
    with connect(server.ws_url) as ws2:
        ws2.send(encode_frame(99, images))
        assert receive(ws2)["frame_id"] == 99


def test_many_connections_each_keep_one_pending_frame(server: LiveServer, images: dict[str, bytes]) -> None:
    with contextlib.ExitStack() as stack:
        sockets = [stack.enter_context(connect(server.ws_url)) for _ in range(3)]
        for frame_id in range(8):
            for ws in sockets:
                ws.send(encode_frame(frame_id, images))
        time.sleep(0.1)
        assert server.metric("fisheye_stream_pending_frames") <= len(sockets)
        for ws in sockets:  # each ends with frame 7: a result, or a 503 when the shared queue of 2 was full
            kinds: dict[int, str] = {}
            while 7 not in kinds:
                answer = receive(ws, timeout=20)
                kinds[answer["frame_id"]] = answer["kind"] if answer["kind"] == "result" else str(answer["status"])
            assert set(kinds.values()) <= {"result", "503"} and "result" in kinds.values()
