"""The KServe v2 routes on a real server, and ``TritonDetector`` against them: the Detector's boxes over tritonclient."""

from __future__ import annotations

import json

import httpx
import numpy as np
import pytest
from service_live import API_KEY, LiveServer

from fisheye_infer.deploy.triton.repository import model_name
from fisheye_infer.errors import ArtifactError, FrameError, InferenceError
from fisheye_infer.runtime.detector import Detector

pytest.importorskip("tritonclient.http", reason="needs the [triton] extra")
from fisheye_infer.deploy.triton import TritonDetector  # noqa: E402


@pytest.fixture(scope="module")
def name(small_model) -> str:
    return model_name(small_model)


def _assert_same(a, b) -> None:
    assert a.cameras_used == b.cameras_used and a.class_names == b.class_names
    np.testing.assert_array_equal(a.labels, b.labels)
    np.testing.assert_allclose(a.boxes, b.boxes, atol=1e-5)
    np.testing.assert_allclose(a.scores, b.scores, atol=1e-6)


def test_triton_detector_gives_the_detectors_answer(
    server: LiveServer, name: str, detector: Detector, images: dict[str, bytes], jpegs: dict[str, bytes]
) -> None:
    remote = TritonDetector(server.url, name)
    assert remote.info.model_id == detector.info.model_id and remote.info.cameras == detector.info.cameras
    got = remote.detect(images)
    assert len(got) > 0
    _assert_same(got, detector.detect(images))
    three = {c: b for c, b in list(jpegs.items())[:3]}  # degraded mode travels as camera_valid
    for a, b in zip(remote.detect_batch([jpegs, three]), detector.detect_batch([jpegs, three])):
        _assert_same(a, b)
    _assert_same(remote.detect(images, score_threshold=0.2, nms=None), detector.detect(images, score_threshold=0.2))


def test_batches_larger_than_max_batch_size_are_split(
    server: LiveServer, name: str, detector: Detector, images: dict[str, bytes]
) -> None:
    frames = [images] * (server.settings.max_batch_frames + 1)
    remote = TritonDetector(server.url, name)
    results = remote.detect_batch(frames)
    assert len(results) == len(frames)
    _assert_same(results[-1], detector.detect(images))


def test_bad_frames_are_refused_before_the_network(server: LiveServer, name: str) -> None:
    remote = TritonDetector(server.url, name)
    with pytest.raises(FrameError, match="model expects 160x160"):
        remote.detect([np.zeros((100, 100, 3), np.uint8)] * 4)


def test_metadata_ready_and_config(client: httpx.Client, name: str, detector: Detector) -> None:
    meta = client.get(f"/v2/models/{name}").json()
    assert {i["name"]: (i["datatype"], i["shape"]) for i in meta["inputs"]} == {
        "images": ("UINT8", [-1, 4, 160, 160, 3]),
        "camera_valid": ("BOOL", [-1, 4]),
    }
    assert [o["name"] for o in meta["outputs"]] == ["boxes", "scores", "labels", "valid"]
    assert client.get(f"/v2/models/{name}/ready").json() == {"name": name, "ready": True}
    assert client.get("/v2/health/ready").status_code == client.get("/v2/health/live").status_code == 200
    config = client.get(f"/v2/models/{name}/config").json()
    assert json.loads(config["parameters"]["fisheye_infer"]["string_value"])["model_id"] == detector.info.model_id


def test_json_tensors(client: httpx.Client, name: str, detector: Detector) -> None:
    images = np.random.default_rng(0).integers(
        0, 10, (1, 4, 160, 160, 3), np.uint8
    )  # one digit per value: the JSON fits in 1 MiB
    valid = np.ones((1, 4), bool)
    body = {
        "inputs": [
            {"name": "images", "datatype": "UINT8", "shape": list(images.shape), "data": images.reshape(-1).tolist()},
            {"name": "camera_valid", "datatype": "BOOL", "shape": [1, 4], "data": [True] * 4},
        ],
        "outputs": [{"name": "scores"}, {"name": "valid"}],
        "id": "req-7",
    }
    response = client.post(f"/v2/models/{name}/infer", json=body)
    assert response.status_code == 200, response.text
    doc = response.json()
    assert doc["id"] == "req-7" and [o["name"] for o in doc["outputs"]] == ["scores", "valid"]
    _, scores, _, keep = detector.run_arrays(images, valid)
    np.testing.assert_allclose(np.array(doc["outputs"][0]["data"]).reshape(scores.shape), scores, atol=1e-6)
    assert doc["outputs"][1]["data"] == keep.reshape(-1).tolist()


def _infer_json(inputs: list[dict]) -> dict:
    return {"inputs": inputs}


GOOD_VALID = {"name": "camera_valid", "datatype": "BOOL", "shape": [1, 4], "data": [True] * 4}


@pytest.mark.parametrize(
    "path, body, status, message",
    [
        ("/v2/models/other/infer", _infer_json([GOOD_VALID]), 404, "model 'other': not served here"),  # unknown model
        ("/v2/models/{name}/versions/7/infer", _infer_json([GOOD_VALID]), 404, "version '7'"),  # unknown version
        (
            "/v2/models/{name}/infer",
            _infer_json([GOOD_VALID]),
            422,
            "expected exactly ['camera_valid', 'images']",
        ),  # an input missing
        (
            "/v2/models/{name}/infer",
            _infer_json([{"name": "images", "datatype": "FP32", "shape": [1, 4, 160, 160, 3], "data": []}, GOOD_VALID]),
            422,
            "input 'images': datatype 'FP32', expected UINT8",
        ),
        (
            "/v2/models/{name}/infer",
            _infer_json([{"name": "images", "datatype": "UINT8", "shape": [1, 4, 80, 80, 3], "data": []}, GOOD_VALID]),
            422,
            "input 'images': shape [1, 4, 80, 80, 3], expected [B, 4, 160, 160, 3]",
        ),
        (
            "/v2/models/{name}/infer",
            _infer_json(
                [{"name": "images", "datatype": "UINT8", "shape": [1, 4, 160, 160, 3], "data": [1, 2]}, GOOD_VALID]
            ),
            422,
            "2 values in data",
        ),
        ("/v2/models/{name}/infer", {"inputs": "x"}, 422, "'inputs' list"),
    ],
)
def test_refusals_name_the_problem(
    client: httpx.Client, name: str, path: str, body: dict, status: int, message: str
) -> None:
    response = client.post(path.format(name=name), json=body)
    assert response.status_code == status, response.text
    assert message in response.json()["error"]


@pytest.mark.parametrize("length", ["999", "9" * 5000, "\u00b2"])  # 5000 digits and "²" were a 500
def test_binary_header_length_is_checked(client: httpx.Client, name: str, length: str) -> None:
    response = client.post(
        f"/v2/models/{name}/infer",
        content=b'{"inputs": []}',
        headers={"Inference-Header-Content-Length": length.encode()},
    )
    assert response.status_code == 400 and "Inference-Header-Content-Length" in response.json()["error"]
    assert len(response.text) < 500


def test_tritonclient_sees_the_servers_refusal(server: LiveServer, name: str) -> None:
    """A server-side refusal reaches the caller as InferenceError with the server's words."""
    remote = TritonDetector(server.url, name)
    with pytest.raises(InferenceError, match=r"HTTP 422.*input 'images': shape \[1, 4, 80, 80, 3\]"):
        remote.run_arrays(np.zeros((1, 4, 80, 80, 3), np.uint8), np.ones((1, 4), bool))


def test_config_max_batch_size_fits_the_body_limit(server: LiveServer, name: str) -> None:
    """Eight 4 x 160 x 160 frames would pass max_batch_frames but not the 1 MiB body limit."""
    remote = TritonDetector(server.url, name)
    assert remote.max_batch_size == (server.settings.max_body_bytes - 16 * 1024) // (4 * (160 * 160 * 3 + 1)) == 3
    frames = remote.max_batch_size + 1
    response = httpx.post(
        f"{server.url}/v2/models/{name}/infer",
        json={
            "inputs": [
                {
                    "name": "images",
                    "datatype": "UINT8",
                    "shape": [frames, 4, 160, 160, 3],
                    "parameters": {"binary_data_size": 1},
                },
                {"name": "camera_valid", "datatype": "BOOL", "shape": [frames, 4], "data": [True] * 4 * frames},
            ]
        },
    )
    assert response.status_code == 422 and f"{frames} frames, at most max_batch_size=3" in response.json()["error"]


def test_unknown_model_or_unreachable_server_is_an_artifact_error(server: LiveServer) -> None:
    with pytest.raises(ArtifactError, match="model 'nope'"):
        TritonDetector(server.url, "nope")
    with pytest.raises(ArtifactError, match="cannot reach the server"):
        TritonDetector("127.0.0.1:9", "nope", timeout_s=2.0)


def test_api_key_applies(keyed_server: LiveServer, name: str, detector: Detector, images: dict[str, bytes]) -> None:
    with pytest.raises(ArtifactError, match="HTTP 401"):
        TritonDetector(keyed_server.url, name)
    _assert_same(
        TritonDetector(keyed_server.url, name, headers={"X-API-Key": API_KEY}).detect(images), detector.detect(images)
    )
    assert httpx.get(f"{keyed_server.url}/v2/health/live").status_code == 200  # health stays open


def _images(**extra: object) -> dict:
    return {"name": "images", "datatype": "UINT8", "shape": [1, 4, 160, 160, 3], "data": [0], **extra}


@pytest.mark.parametrize(
    "body, status, message",
    [
        (b"[" * 100_000 + b"]" * 100_000, 400, "nests arrays or objects too deep"),
        (b'{"inputs": [], "id": ' + b"[" * 100_000 + b"]" * 100_000 + b"}", 400, "nests arrays or objects too deep"),
        (b'{"inputs": [], "id": ' + b"7" * 5000 + b"}", 400, "Exceeds the limit (4300 digits)"),
        ({"inputs": [GOOD_VALID], "id": 7}, 422, "id: expected a string, got int"),
        ({"inputs": [{"name": ["images"]}, GOOD_VALID]}, 422, "inputs[0]: expected an object whose 'name' is a string"),
        (
            {"inputs": [_images(parameters=[1]), GOOD_VALID]},
            422,
            "input 'images'.parameters: expected an object, got list",
        ),
        (
            {"inputs": [_images(parameters="x"), GOOD_VALID]},
            422,
            "input 'images'.parameters: expected an object, got str",
        ),
        (
            {"inputs": [_images(), GOOD_VALID], "parameters": [1]},
            422,
            "request.parameters: expected an object, got list",
        ),
        (
            {"inputs": [_images(), GOOD_VALID], "parameters": "x"},
            422,
            "request.parameters: expected an object, got str",
        ),
        (
            {"inputs": [_images(), GOOD_VALID], "outputs": [{"name": "boxes", "parameters": [1]}]},
            422,
            "output 'boxes'.parameters: expected an object, got list",
        ),
        (
            {"inputs": [_images(), GOOD_VALID], "outputs": [{"name": "boxes", "parameters": "x"}]},
            422,
            "output 'boxes'.parameters: expected an object, got str",
        ),
        ({"inputs": [GOOD_VALID, {**GOOD_VALID, "name": "images", "datatype": "x" * 10_000}]}, 422, "characters)"),
        ({"inputs": [_images(data=[300]), GOOD_VALID]}, 422, "input 'images': data cannot be read as UINT8"),
    ],
)
def test_malformed_requests_are_refused_by_field(
    client: httpx.Client, name: str, body: bytes | dict, status: int, message: str
) -> None:
    """Each was a 500 "internal error": RecursionError, an unhashable name, parameters that are not an object."""
    content = body if isinstance(body, bytes) else json.dumps(body).encode()
    response = client.post(f"/v2/models/{name}/infer", content=content, headers={"Content-Type": "application/json"})
    assert response.status_code == status, response.text
    assert message in response.json()["error"] and len(response.text) < 2000
