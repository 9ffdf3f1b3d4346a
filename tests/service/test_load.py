"""Under load: a full queue answers 503 + Retry-After at once, micro-batching groups concurrent
requests, and a client that leaves mid-request gives its place back."""

from __future__ import annotations

import http.client
import json
import socket
import threading
import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest
from service_live import API_KEY, LiveServer, multipart


def _post_together(url: str, files: list, count: int, headers: dict[str, str] | None = None) -> list[httpx.Response]:
    barrier = threading.Barrier(count, timeout=30)

    def post(_: int) -> httpx.Response:
        with httpx.Client(base_url=url, timeout=30, headers=headers) as client:
            barrier.wait()
            return client.post("/detect", files=files)

    with ThreadPoolExecutor(count) as pool:
        return list(pool.map(post, range(count)))


def test_full_queue_answers_503_with_retry_after_at_once(server: LiveServer, images: dict[str, bytes]) -> None:
    responses = _post_together(server.url, multipart(images), 10)  # queue_size=2, one worker
    statuses = sorted(r.status_code for r in responses)
    assert set(statuses) == {200, 503}, statuses  # every request answered or explicitly refused
    refused = [r for r in responses if r.status_code == 503]
    assert all(r.headers["Retry-After"] == "1" and r.json()["field"] == "queue" for r in refused)
    assert "queue_size=2" in refused[0].json()["error"]
    assert server.wait_metric("fisheye_inflight", lambda v: v == 0) == 0
    with httpx.Client(base_url=server.url, timeout=20) as client:
        assert client.post("/detect", files=multipart(images)).status_code == 200


def _headers_only(port: int) -> socket.socket:
    """A POST /detect whose headers announce a 1 kB multipart body that is never sent."""
    sock = socket.create_connection(("127.0.0.1", port), timeout=20)
    sock.sendall(
        b"POST /detect HTTP/1.1\r\nHost: 127.0.0.1\r\nContent-Type: multipart/form-data; boundary=b\r\n"
        b"Content-Length: 1000\r\n\r\n"
    )
    return sock


def test_full_queue_refuses_before_reading_the_body(server: LiveServer, images: dict[str, bytes]) -> None:
    """503 at once: with the queue full of decoded work, a client gets its answer without having sent a byte of its body."""
    batch = [part for i in range(8) for part in multipart(images, f"{i}.")]  # each keeps the worker ~0.7 s
    with ThreadPoolExecutor(3) as pool:
        busy = [
            pool.submit(httpx.post, f"{server.url}/detect/batch", files=batch, timeout=60) for _ in range(3)
        ]  # one runs, two wait
        assert (
            server.wait_metric("fisheye_queue_depth", lambda v: v == server.settings.queue_size)
            == server.settings.queue_size
        )
        with _headers_only(server.port) as refused:
            answer = http.client.HTTPResponse(refused)
            answer.begin()
            body = json.loads(answer.read())
        assert answer.status == 503 and answer.getheader("Retry-After") == "1"
        assert body["field"] == "queue" and "queue_size=2" in body["error"]
        assert [f.result().status_code for f in busy] == [200] * 3
    assert server.wait_metric("fisheye_inflight", lambda v: v == 0) == 0
    assert server.metric("fisheye_queue_depth") == 0


def test_client_leaving_mid_request_gives_its_place_back(server: LiveServer, images: dict[str, bytes]) -> None:
    gone_before = server.metric("fisheye_requests_total", endpoint="/detect", status="499")
    batch = [part for i in range(8) for part in multipart(images, f"{i}.")]
    with httpx.Client(base_url=server.url, timeout=30) as busy:
        holder = threading.Thread(target=lambda: busy.post("/detect/batch", files=batch))  # keeps the worker ~0.7 s
        holder.start()
        deadline = time.monotonic() + 10
        while (
            not (server.metric("fisheye_inflight") == 1 and server.metric("fisheye_queue_depth") == 0)
            and time.monotonic() < deadline
        ):
            time.sleep(0.01)  # until the batch is running
        with pytest.raises(httpx.ReadTimeout):  # queued behind the batch, then the client gives up
            httpx.post(f"{server.url}/detect", files=multipart(images), timeout=httpx.Timeout(5.0, read=0.1))
        holder.join()
    assert (
        server.wait_metric("fisheye_requests_total", lambda v: v == gone_before + 1, endpoint="/detect", status="499")
        == gone_before + 1
    )
    assert server.wait_metric("fisheye_inflight", lambda v: v == 0) == 0
    assert server.metric("fisheye_queue_depth") == 0


def test_microbatching_groups_concurrent_requests(keyed_server: LiveServer, images: dict[str, bytes]) -> None:
    before = keyed_server.metric("fisheye_batch_frames_count")
    frames_before = keyed_server.metric("fisheye_batch_frames_sum")
    responses = _post_together(keyed_server.url, multipart(images), 4, headers={"X-API-Key": API_KEY})
    assert [r.status_code for r in responses] == [200] * 4
    sizes = [r.json()["batch_size"] for r in responses]
    assert max(sizes) > 1, sizes  # at least two requests ran in one detect_batch call
    runs = keyed_server.metric("fisheye_batch_frames_count") - before
    assert keyed_server.metric("fisheye_batch_frames_sum") - frames_before == 4 and runs < 4
    scores = [[d["score"] for d in r.json()["detections"]] for r in responses]
    assert all(s == pytest.approx(scores[0], abs=1e-5) for s in scores)  # grouping does not change the answer


def test_microbatched_requests_keep_their_own_options(keyed_server: LiveServer, images: dict[str, bytes]) -> None:
    barrier = threading.Barrier(2, timeout=30)

    def post(options: dict[str, str]) -> httpx.Response:
        with httpx.Client(base_url=keyed_server.url, timeout=30, headers={"X-API-Key": API_KEY}) as client:
            barrier.wait()
            return client.post("/detect", files=multipart(images), data=options)

    with ThreadPoolExecutor(2) as pool:
        plain, filtered = pool.map(post, [{}, {"classes": "Car"}])
    assert plain.status_code == filtered.status_code == 200
    assert {d["class_name"] for d in filtered.json()["detections"]} <= {"Car"}
    assert len(plain.json()["detections"]) > len(filtered.json()["detections"])
