"""Hostile and careless clients against a real ``fisheye-infer serve`` on loopback, and what they get.

    python tests/service/probe_service.py MODEL.onnx [--images DIR] [--json out.json]

A reliability check of the service, run by hand (pytest does not collect it; ``test_hardening.py``
asserts the same behaviours one by one). It starts the service as ``fisheye-infer serve`` does
(``service_live.LiveServer``: ``build_server`` with an API key and the default limits) on a free
127.0.0.1 port, runs each probe with raw sockets or httpx and sorts the outcomes: the status code
answered, ``reset`` (the connection was reset before an answer could be read), ``closed`` (closed
without an answer) or ``hang`` (no answer within the probe's bound). Last, it holds 9 stalled
uploads open (headers and 100 bytes of a 1 MB body) and times valid ``/detect`` requests meanwhile.
Exits 1 when any probe got a 5xx, a reset, a hang or an unexpected outcome.
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import gzip
import json
import logging
import socket
import statistics
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import httpx
import numpy as np
from service_live import API_KEY as KEY
from service_live import LiveServer

from fisheye_infer.runtime.detector import Detector
from fisheye_infer.service.settings import ServiceSettings

Outcome = str  # "200", "422", ..., "reset", "closed", "hang"


def _stalled(port: int, path: str = "/detect") -> socket.socket:
    sock = socket.create_connection(("127.0.0.1", port), timeout=60)
    sock.sendall(
        f"POST {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nX-API-Key: {KEY}\r\nContent-Length: 1000000\r\n"
        "Content-Type: multipart/form-data; boundary=bnd\r\n\r\n".encode()
        + b"--bnd\r\n"
        + b"x" * 93
    )
    return sock


def _many_scan_jpeg(image: np.ndarray, copies: int) -> bytes:
    data = cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_PROGRESSIVE, 1])[1].tobytes()
    first = data.index(b"\xff\xda")
    second = data.index(b"\xff\xda", first + 2)
    return data[:second] + data[first:second] * copies + data[second:]


def probes(url: str, port: int, pngs: dict[str, bytes], jpegs: dict[str, bytes]) -> dict[str, Callable[[], Outcome]]:
    """Each probe by name: a call that sends one hostile or careless request and returns its outcome."""
    cams = list(pngs)
    front = cams[0]
    key = {"X-API-Key": KEY}
    files = [(c, (f"{c}.png", b, "image/png")) for c, b in pngs.items()]
    rng = np.random.default_rng(0)
    jpeg = jpegs[front]
    sos = jpeg.index(b"\xff\xda")
    header_end = sos + 2 + ((jpeg[sos + 2] << 8) | jpeg[sos + 3])
    corrupt = jpeg[:header_end] + rng.integers(0, 256, 20000, dtype=np.uint8).tobytes() + b"\xff\xd9"
    image = cv2.imdecode(np.frombuffer(jpeg, np.uint8), cv2.IMREAD_COLOR)
    body = httpx.Request("POST", url, files=files).read()
    boundary = body[2 : body.index(b"\r\n")].decode()
    multipart = {"content-type": f"multipart/form-data; boundary={boundary}", **key}

    def post(path: str = "/detect", timeout: float = 30, **kwargs: object) -> Outcome:
        try:
            return str(httpx.post(url + path, timeout=timeout, **kwargs).status_code)  # type: ignore[arg-type]
        except httpx.ReadTimeout:
            return "hang"
        except (httpx.RemoteProtocolError, httpx.ReadError, httpx.WriteError):
            return "reset"

    def with_front(data: bytes, kind: str = "image/jpeg") -> list:
        return [(c, (f"{c}.bin", data, kind) if c == front else (f"{c}.bin", b, "image/png")) for c, b in pngs.items()]

    def urllib_40mib() -> Outcome:
        headers = {"Content-Type": "application/json", **key}
        request = urllib.request.Request(url + "/detect", data=b"x" * (40 << 20), headers=headers)
        try:
            return str(urllib.request.urlopen(request, timeout=30).status)
        except urllib.error.HTTPError as exc:
            return str(exc.code)
        except (urllib.error.URLError, ConnectionError):
            return "reset"

    def smuggled() -> Outcome:
        data = (
            f"POST /detect HTTP/1.1\r\nHost: x\r\nX-API-Key: {KEY}\r\nContent-Type: application/json\r\n"
            "Content-Length: 4\r\nTransfer-Encoding: chunked\r\n\r\n0\r\n\r\n"
            "GET /healthz HTTP/1.1\r\nHost: x\r\n\r\n"
        ).encode()
        with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
            sock.sendall(data)
            seen = b""
            with contextlib.suppress(OSError):
                while chunk := sock.recv(65536):
                    seen += chunk
        if seen.count(b"HTTP/1.1 ") > 1:
            return "smuggled request answered"
        return seen.split(b" ", 2)[1].decode() if seen else "closed"

    def trickle(head: bytes, data: bytes) -> Outcome:  # ``head`` at once, then one byte of ``data`` a second
        with socket.create_connection(("127.0.0.1", port), timeout=60) as sock:
            sock.sendall(head)
            sock.settimeout(1.0)
            for byte in data:
                try:
                    sock.sendall(bytes([byte]))
                    answer = sock.recv(65536)
                except TimeoutError:
                    continue
                except (ConnectionResetError, BrokenPipeError):
                    return "reset"
                return answer.split(b" ", 2)[1].decode() if answer else "closed"
        return "hang"

    json_images = {c: base64.b64encode(b).decode() for c, b in pngs.items()}
    twice = [("0." + c, f) for c, f in files] + [("00." + front, files[0][1])]
    model_request = f"GET /model HTTP/1.1\r\nHost: x\r\nX-API-Key: {KEY}\r\n\r\n".encode()
    detect_head = (
        f"POST /detect HTTP/1.1\r\nHost: x\r\nX-API-Key: {KEY}\r\n"
        f"Content-Type: {multipart['content-type']}\r\nContent-Length: {len(body)}\r\n\r\n"
    ).encode()

    def many_classes() -> Outcome:
        answer = httpx.post(
            url + "/detect",
            json={"images": json_images, "classes": [f"c{i}" for i in range(100_000)]},
            headers=key,
            timeout=30,
        )
        return f"{answer.status_code} ({len(answer.content)} bytes answered)"

    return {
        "stalled-queue: see latency below": lambda: "n/a",
        "many-scan progressive JPEG": lambda: post(files=with_front(_many_scan_jpeg(image, 3000)), headers=key),
        "corrupt JPEG data": lambda: post(files=with_front(corrupt), headers=key),
        "non-ASCII digit part name": lambda: post(
            "/detect/batch", files=[("\u00b2." + c, f) for c, f in files], headers=key
        ),
        "same camera twice (0. / 00.)": lambda: post("/detect/batch", files=twice, headers=key),
        "slow headers (1 byte/s)": lambda: trickle(b"", model_request),
        "Content-Length + Transfer-Encoding": smuggled,
        "40 MiB body, urllib": urllib_40mib,
        "/docs without the key": lambda: str(httpx.get(url + "/docs", timeout=10).status_code),
        "/openapi.json without the key": lambda: str(httpx.get(url + "/openapi.json", timeout=10).status_code),
        "10 kB camera name": lambda: post(
            files=[*files, ("x" * 10000, ("a.png", pngs[front], "image/png"))], headers=key
        ),
        "gzip body": lambda: post(content=gzip.compress(body), headers={**multipart, "Content-Encoding": "gzip"}),
        "unterminated multipart": lambda: post(content=body[:-200], headers=multipart),
        "5000-digit JSON integer": lambda: post(
            content=b'{"images": {}, "score_threshold": ' + b"9" * 5000 + b"}",
            headers={"Content-Type": "application/json", **key},
        ),
        "100k unknown classes, JSON": many_classes,
        "slow body (1 byte/s)": lambda: trickle(detect_head, body),
        "base64 JSON, valid": lambda: post(json={"images": json_images}, headers=key),
    }


def latency_with_stalled(
    url: str, port: int, pngs: dict[str, bytes], stalled: int = 9, requests: int = 20
) -> dict[str, object]:
    """Valid ``/detect`` requests timed while ``stalled`` uploads hold their connections open."""
    files = [(c, (f"{c}.png", b, "image/png")) for c, b in pngs.items()]
    with contextlib.ExitStack() as stack:
        for _ in range(stalled):
            stack.enter_context(_stalled(port))
        time.sleep(0.5)
        times, statuses = [], []
        with httpx.Client(base_url=url, timeout=30, headers={"X-API-Key": KEY}) as client:
            for _ in range(requests):
                t0 = time.perf_counter()
                statuses.append(client.post("/detect", files=files).status_code)
                times.append((time.perf_counter() - t0) * 1e3)
    return {
        "stalled_uploads": stalled,
        "requests": requests,
        "statuses": sorted(set(statuses)),
        "median_ms": round(statistics.median(times), 1),
        "max_ms": round(max(times), 1),
    }


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model")
    parser.add_argument(
        "--images", type=Path, help="folder with <camera>.png (default: black frames of the model's size)"
    )
    parser.add_argument("--json", type=Path, help="write the outcomes here")
    args = parser.parse_args()

    detector = Detector(args.model, threads=1)
    width, height = detector.info.image_size
    frames = {
        c: cv2.imread(str(args.images / f"{c}.png")) if args.images else np.zeros((height, width, 3), np.uint8)
        for c in detector.info.cameras
    }
    pngs = {c: cv2.imencode(".png", im)[1].tobytes() for c, im in frames.items()}
    jpegs = {c: cv2.imencode(".jpg", im)[1].tobytes() for c, im in frames.items()}
    live = LiveServer(ServiceSettings(model_path=args.model, threads=1, api_key=KEY, port=0), detector)
    for name in ("uvicorn.error", "uvicorn.access"):  # the probes' malformed requests are expected
        logging.getLogger(name).setLevel(logging.ERROR)
    live.start()
    try:
        table = probes(live.url, live.port, pngs, jpegs)
        with ThreadPoolExecutor(4) as pool:  # the slow probes run beside the quick ones
            futures = {name: pool.submit(run) for name, run in table.items()}
            outcomes = {name: f.result() for name, f in futures.items()}
        del outcomes["stalled-queue: see latency below"]
        latency = latency_with_stalled(live.url, live.port, pngs)
    finally:
        live.stop()

    counts = {"2xx": 0, "4xx": 0, "5xx": 0, "reset": 0, "closed": 0, "hang": 0, "other": 0}
    for outcome in outcomes.values():
        head = outcome.split()[0]
        kind = f"{head[0]}xx" if head[:1] in "245" and head[:3].isdigit() else head if head in counts else "other"
        counts[kind] += 1
    column = max(map(len, outcomes))
    for name, outcome in outcomes.items():
        print(f"{name:<{column}}  {outcome}")
    print("counts:", ", ".join(f"{k} {v}" for k, v in counts.items()))
    print(
        f"valid /detect while {latency['stalled_uploads']} stalled uploads are held: statuses {latency['statuses']}, "
        f"median {latency['median_ms']} ms, max {latency['max_ms']} ms over {latency['requests']} requests"
    )
    if args.json:
        args.json.write_text(json.dumps({"outcomes": outcomes, "counts": counts, "latency": latency}, indent=2))
    return 0 if counts["5xx"] == counts["reset"] == counts["hang"] == counts["other"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
