"""WebSocket /stream with track=true: every answer carries the connection's own tracks."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
from service_live import LiveServer
from websockets.sync.client import connect

from fisheye_infer.service.protocol import encode_frame
from fisheye_infer.service.schemas import StreamResult


def _answers(ws: Any, images: dict[str, bytes], count: int) -> list[dict[str, Any]]:
    answers = []
    for frame_id in range(count):
        ws.send(encode_frame(frame_id, images))
        answers.append(json.loads(ws.recv(timeout=20)))
    return answers


def test_each_connection_tracks_on_its_own(server: LiveServer, images: dict[str, bytes]) -> None:
    url = server.ws_url + "?track=true&track_score=0"
    with connect(url) as first, connect(url) as second:
        a = _answers(first, images, 3)
        b = _answers(second, images, 3)
    for answer in a + b:
        StreamResult.model_validate(answer)
        assert answer["kind"] == "result" and answer["tracks"]
    ids = [{t["track_id"] for t in answer["tracks"]} for answer in a]
    assert ids[0] & ids[2]  # the same frame again: the same objects keep their ids
    ages = [sorted(t["age"] for t in answer["tracks"]) for answer in (a[0], a[2], b[0])]
    assert max(ages[1]) == max(ages[0]) + 2  # the first connection's tracks grew two frames older
    assert ages[2] == ages[0]  # the second connection's tracks start afresh: a tracker shared would continue them
    for track in a[2]["tracks"]:  # each track's velocity with its covariance, certain where seen three times
        cov = np.array(track["velocity_covariance"])
        assert (
            cov.shape == (2, 2) and np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) >= -1e-6 * np.trace(cov))
        )
    oldest = max(a[2]["tracks"], key=lambda t: t["age"])
    youngest_first = min(a[0]["tracks"], key=lambda t: t["age"])
    assert np.trace(oldest["velocity_covariance"]) < np.trace(youngest_first["velocity_covariance"])


def test_tracks_are_asked_for(server: LiveServer, images: dict[str, bytes]) -> None:
    with connect(server.ws_url) as ws:
        (answer,) = _answers(ws, images, 1)
    assert "tracks" not in answer
    with connect(server.ws_url + "?track=maybe") as ws:
        refused = json.loads(ws.recv(timeout=10))
    assert refused["kind"] == "error" and refused["field"] == "track" and "true or false" in refused["error"]
