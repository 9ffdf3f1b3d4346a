"""POST /detect and /detect/batch on a real server: the same boxes as the Detector, in both body forms."""

from __future__ import annotations

import base64

import httpx
import numpy as np
import pytest
from service_live import LiveServer, multipart

from fisheye_infer.runtime.detector import Detector

STAGES = {"queue_wait", "decode", "preprocess", "inference", "postprocess"}


def test_detect_multipart_gives_the_detectors_boxes(
    client: httpx.Client, images: dict[str, bytes], detector: Detector
) -> None:
    response = client.post("/detect", files=multipart(images))
    assert response.status_code == 200, response.text
    body = response.json()
    reference = detector.detect(images)
    assert body["model_id"] == detector.info.model_id
    assert body["cameras_used"] == list(detector.info.cameras)
    assert set(body["timings_ms"]) == STAGES and body["timings_ms"]["inference"] > 0
    assert body["batch_size"] == 1
    assert len(body["detections"]) == len(reference) == len(body["records"]) > 0
    np.testing.assert_allclose([d["score"] for d in body["detections"]], reference.scores, atol=1e-6)
    assert body["detections"][0].keys() == reference.to_dicts()[0].keys()
    assert body["records"][0]["detection_name"] == reference.to_nuscenes()[0]["detection_name"]


def test_detect_json_base64_equals_multipart(client: httpx.Client, jpegs: dict[str, bytes]) -> None:
    as_json = client.post("/detect", json={"images": {c: base64.b64encode(b).decode() for c, b in jpegs.items()}})
    as_form = client.post("/detect", files=multipart(jpegs, content_type="image/jpeg"))
    assert as_json.status_code == as_form.status_code == 200
    assert as_json.json()["detections"] == as_form.json()["detections"]


@pytest.mark.parametrize(
    "options, check",
    [
        ({"score_threshold": "0.3"}, lambda d: all(x["score"] >= 0.3 for x in d)),  # threshold keeps only high scores
        (
            {"classes": "Car,Pedestrian"},
            lambda d: {x["class_name"] for x in d} <= {"Car", "Pedestrian"},
        ),  # class filter
        ({"nms": "circle", "score_threshold": "0.05"}, lambda d: len(d) >= 1),  # NMS runs and keeps the best box
    ],
)
def test_options_apply(client: httpx.Client, images: dict[str, bytes], options: dict[str, str], check) -> None:
    full = client.post("/detect", files=multipart(images)).json()["detections"]
    response = client.post("/detect", files=multipart(images), data=options)
    assert response.status_code == 200, response.text
    got = response.json()["detections"]
    assert check(got) and len(got) <= len(full)


def test_missing_camera_runs_degraded_when_allowed(client: httpx.Client, images: dict[str, bytes]) -> None:
    three = {c: b for c, b in list(images.items())[:3]}
    response = client.post("/detect", files=multipart(three), data={"allow_missing_cameras": "true"})
    assert response.status_code == 200, response.text
    assert response.json()["cameras_used"] == list(three)


def test_batch_multipart_runs_one_call_in_order(
    client: httpx.Client, images: dict[str, bytes], jpegs: dict[str, bytes], detector: Detector
) -> None:
    parts = multipart(images, "0.") + multipart(jpegs, "1.", "image/jpeg") + multipart(images, "2.")
    response = client.post("/detect/batch", files=parts)
    assert response.status_code == 200, response.text
    frames = response.json()["frames"]
    assert [f["batch_size"] for f in frames] == [3, 3, 3]

    def scores(i: int) -> list[float]:
        return [d["score"] for d in frames[i]["detections"]]

    np.testing.assert_allclose(scores(0), scores(2), atol=1e-6)  # the same frame twice in one batch
    assert len(scores(1)) != len(scores(0)) or not np.allclose(scores(1), scores(0))
    reference = detector.detect(jpegs)
    np.testing.assert_allclose([d["score"] for d in frames[1]["detections"]], reference.scores, atol=1e-6)


def test_batch_json(client: httpx.Client, images: dict[str, bytes]) -> None:
    frame = {"images": {c: base64.b64encode(b).decode() for c, b in images.items()}}
    response = client.post("/detect/batch", json={"frames": [frame, frame], "score_threshold": 0.2})
    assert response.status_code == 200, response.text
    body = response.json()
    assert len(body["frames"]) == 2 and all(d["score"] >= 0.2 for f in body["frames"] for d in f["detections"])


def test_model_info(client: httpx.Client, detector: Detector) -> None:
    body = client.get("/model").json()
    info = detector.info
    assert body["cameras"] == list(info.cameras) and body["classes"] == list(info.classes)
    assert body["image_size"] == {"width": 160, "height": 160}
    assert body["rig_hash"] == info.meta.rig_hash and body["model_id"] == info.model_id
    assert body["limits"]["queue_size"] == 2 and body["limits"]["stream_protocol_version"] == 1
    assert body["limits"]["body_timeout_s"] == 30 and body["limits"]["max_jpeg_scans"] == 64


def test_health_ready_and_docs(client: httpx.Client) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    assert client.get("/readyz").json()["status"] == "ready"
    assert client.get("/docs").status_code == 200
    schema = client.get("/openapi.json").json()
    body = schema["paths"]["/detect"]["post"]["requestBody"]["content"]
    assert set(body) == {"multipart/form-data", "application/json"}
    multipart_schema = schema["components"]["schemas"]["DetectMultipart"]
    assert "fisheye_camera_front" in multipart_schema["required"]
    for name in (
        "DetectResponse",
        "BatchResponse",
        "ModelInfo",
        "ErrorOut",
        "DetectJsonRequest",
        "BatchJsonRequest",
        "StreamResult",
        "StreamError",
    ):
        assert name in schema["components"]["schemas"]


def test_metrics_count_requests_and_stages(server: LiveServer, client: httpx.Client, images: dict[str, bytes]) -> None:
    before = server.metric("fisheye_requests_total", endpoint="/detect", status="200")
    assert client.post("/detect", files=multipart(images)).status_code == 200
    text = client.get("/metrics").text
    assert server.metric("fisheye_requests_total", endpoint="/detect", status="200") == before + 1
    for stage in STAGES:
        assert f'fisheye_stage_duration_seconds_count{{stage="{stage}"}}' in text
    assert "fisheye_queue_depth 0.0" in text and "fisheye_stream_dropped_frames_total" in text
    assert 'fisheye_request_duration_seconds_bucket{endpoint="/detect"' in text
