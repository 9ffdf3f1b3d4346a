"""The torch-free Detector on real exported models in real ONNX Runtime."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import cv2
import numpy as np
import pytest

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ArtifactError, ConfigError, FrameError, OptionError
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.runtime.nms import NmsConfig
from fisheye_infer.scenes.render import Renderer, random_scene


@pytest.fixture(scope="module")
def frame(rig: Rig) -> dict[str, np.ndarray]:
    return Renderer(texture_seed=2).render(rig, random_scene(np.random.default_rng(42)))


@pytest.fixture(scope="module")
def detector(bevdet_export) -> Detector:
    return Detector(bevdet_export.onnx, threads=2)


def test_info_comes_from_the_metadata(detector: Detector, rig: Rig) -> None:
    info = detector.info
    assert info.architecture == "fisheye-bevdet" and info.cameras == tuple(rig.names)
    assert info.image_size == (800, 800) and info.num_boxes == 200 and info.rig == rig
    assert info.classes[0] == "Car" and "CPUExecutionProvider" in info.providers
    assert detector.ready


def test_returns_the_files_official_output_set(detector: Detector, bevdet_export, frame) -> None:
    """The Detector adds decoding and the official output filter to the file, nothing else. (The
    file's parity with PyTorch is the export self-check's, tests/export.)"""
    from fisheye_infer.export.verify import run_onnx

    images = np.stack([frame[n] for n in detector.info.cameras])[None]
    ref = run_onnx(bevdet_export.onnx, images, np.ones((1, 4), bool), 2)
    keep = ref["valid"][0]
    dets = detector.detect(frame)
    assert len(dets) == int(keep.sum()) > 0
    np.testing.assert_array_equal(dets.labels, ref["labels"][0][keep])
    np.testing.assert_array_equal(dets.boxes, ref["boxes"][0][keep])
    np.testing.assert_array_equal(dets.scores, ref["scores"][0][keep])
    assert set(dets.timings_ms) == {"decode", "preprocess", "inference", "postprocess"}


def test_every_input_form_gives_the_same_result(detector: Detector, frame, tmp_path: Path) -> None:
    names = detector.info.cameras
    paths = {}
    for name in names:
        paths[name] = tmp_path / f"{name}.png"
        cv2.imwrite(str(paths[name]), frame[name])
    encoded = {n: cv2.imencode(".png", frame[n])[1].tobytes() for n in names}
    reference = detector.detect(frame)
    for form in ([frame[n] for n in names], encoded, paths, [str(paths[n]) for n in names]):
        got = detector.detect(form)
        np.testing.assert_array_equal(got.boxes, reference.boxes)
        np.testing.assert_array_equal(got.scores, reference.scores)
    # the Detector's map_images (which load_frames uses when several images need decoding) runs on its own threads
    assert all(
        name.startswith("fisheye-decode")
        for name in detector.map_images(lambda _: threading.current_thread().name, range(8))
    )


def test_degraded_mode_reports_cameras_used(detector: Detector, frame) -> None:
    partial = dict(frame, fisheye_camera_rear=None)
    del partial["fisheye_camera_left"]
    dets = detector.detect(partial)
    assert dets.cameras_used == ("fisheye_camera_front", "fisheye_camera_right")
    full = detector.detect(frame)
    assert dets.scores.tolist() != full.scores.tolist()


def test_batch_equals_single_frames(detector: Detector, frame, rig: Rig) -> None:
    other = Renderer(texture_seed=3).render(rig, random_scene(np.random.default_rng(7)))
    batch = detector.detect_batch([frame, other])
    for one, dets in zip((frame, other), batch):
        single = detector.detect(one)
        np.testing.assert_allclose(dets.boxes, single.boxes, atol=1e-4)
        np.testing.assert_array_equal(dets.labels, single.labels)


def test_concurrent_callers_get_serial_answers(detector: Detector, frame, rig: Rig) -> None:
    frames = [frame] + [Renderer(texture_seed=s).render(rig, random_scene(np.random.default_rng(s))) for s in (1, 2)]
    serial = [detector.detect(f) for f in frames]
    jobs = [frames[i % 3] for i in range(9)]
    with ThreadPoolExecutor(max_workers=3) as pool:
        results = list(pool.map(detector.detect, jobs))
    for i, dets in enumerate(results):
        np.testing.assert_array_equal(dets.boxes, serial[i % 3].boxes)
        np.testing.assert_array_equal(dets.labels, serial[i % 3].labels)


def test_options_threshold_classes_and_nms(detector: Detector, frame) -> None:
    full = detector.detect(frame)
    thresholded = detector.detect(frame, score_threshold=float(np.median(full.scores)))
    assert 0 < len(thresholded) < len(full) and thresholded.scores.min() >= np.median(full.scores)
    cars = detector.detect(frame, classes=["Car"])
    assert set(cars.names) <= {"Car"}
    suppressed = detector.detect(frame, nms=NmsConfig(kind="circle", radius=4.0))
    assert len(suppressed) < len(full)
    centres = suppressed.boxes[:, :2]
    for label in np.unique(suppressed.labels):
        same = centres[suppressed.labels == label]
        d = np.linalg.norm(same[:, None] - same[None], axis=-1) + np.eye(len(same)) * 1e9
        assert d.min() >= 4.0


@pytest.mark.parametrize(
    ("frame_", "message"),
    [
        (
            {"fisheye_camera_roof": np.zeros((800, 800, 3), np.uint8)},
            "camera 'fisheye_camera_roof': not a camera of this model",
        ),
        (
            {"fisheye_camera_front": np.zeros((600, 800, 3), np.uint8)},
            "camera 'fisheye_camera_front': image is 800x600, model expects 800x800",
        ),
        ({"fisheye_camera_left": b"\x89PNG garbage"}, "camera 'fisheye_camera_left': the bytes are not a decodable"),
        ([np.zeros((800, 800, 3), np.uint8)] * 2, "got 2 images, expected 4"),
    ],
)
def test_bad_frames_raise_frame_error(detector: Detector, frame_, message: str) -> None:
    with pytest.raises(FrameError, match=message):
        detector.detect(frame_)


def test_bad_model_files(tmp_path: Path) -> None:
    with pytest.raises(ArtifactError, match="no such file"):
        Detector(tmp_path / "missing.onnx")
    junk = tmp_path / "junk.onnx"
    junk.write_bytes(b"not a model")
    with pytest.raises(ArtifactError, match="cannot load it"):
        Detector(junk)


def test_tampered_rig_is_refused(bevdet_export, tmp_path: Path) -> None:
    onnx = pytest.importorskip("onnx")
    import json

    model = onnx.load(str(bevdet_export.onnx))
    for p in model.metadata_props:
        if p.key == "fisheye_infer":
            doc = json.loads(p.value)
            doc["rig"]["cameras"][0]["cam2lidar"][0][3] += 0.1  # the rig moved, its hash did not
            p.value = json.dumps(doc)
    tampered = tmp_path / "tampered.onnx"
    onnx.save(model, str(tampered))
    with pytest.raises(ArtifactError, match="rig_hash"):
        Detector(tampered)


def test_providers_default_to_cpu_and_unknown_ones_are_named(small_export) -> None:
    assert Detector(small_export.onnx, threads=1, warmup=False).info.providers == ("CPUExecutionProvider",)
    auto = Detector(small_export.onnx, threads=1, providers="auto")  # whatever this onnxruntime offers, CPU last
    assert auto.info.providers[-1] == "CPUExecutionProvider" and auto.ready
    with pytest.raises(ValueError, match="providers: NoSuchExecutionProvider not offered by the installed onnxruntime"):
        Detector(small_export.onnx, providers=["NoSuchExecutionProvider"])
    # with options, as ONNX Runtime takes them (CUDA's {"use_tf32": "0"} for fp32-exact results on a GPU)
    with_options = Detector(small_export.onnx, threads=1, providers=[("CPUExecutionProvider", {})], warmup=False)
    assert with_options.info.providers == ("CPUExecutionProvider",)
    with pytest.raises(
        ValueError,
        match=r"providers: expected a provider name or a \(name, options dict\) pair, got \('CPUExecutionProvider',\)",
    ):
        Detector(small_export.onnx, providers=[("CPUExecutionProvider",)])  # type: ignore[list-item]
    with pytest.raises(ValueError, match="providers: 'auto' stands alone"):
        Detector(small_export.onnx, providers=["auto", "CPUExecutionProvider"])


def test_a_provider_that_does_not_start_is_an_error_not_a_cpu_fallback(
    small_export, monkeypatch: pytest.MonkeyPatch
) -> None:
    """This onnxruntime is told it has CUDA; ONNX Runtime then runs the session on the CPU (a CUDA provider
    without a GPU or its libraries does the same): asked for by name, that is refused."""
    import fisheye_infer.runtime.session as session

    monkeypatch.setattr(session, "available_providers", lambda: ["CUDAExecutionProvider", "CPUExecutionProvider"])
    with (
        pytest.warns(UserWarning),
        pytest.raises(
            ConfigError, match="ONNX Runtime did not start CUDAExecutionProvider .*runs on CPUExecutionProvider"
        ),
    ):
        Detector(small_export.onnx, threads=1, providers=["CUDAExecutionProvider", "CPUExecutionProvider"])


def test_auto_drops_a_provider_that_fails_to_start(
    small_export, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """onnxruntime-gpu lists TensorRT without its libraries, and creating a session with it raises: 'auto' tries the
    next provider, a named list does not. No TensorRT here, so the session's creation fails as it does there."""
    import onnxruntime as ort

    import fisheye_infer.runtime.session as session

    real = ort.InferenceSession

    def without_tensorrt(path, options, providers, enable_fallback):  # type: ignore[no-untyped-def]
        if providers[0] == "TensorrtExecutionProvider":
            raise RuntimeError("libnvinfer.so.10: cannot open shared object file: No such file or directory")
        return real(path, options, providers=providers, enable_fallback=enable_fallback)

    monkeypatch.setattr(session, "available_providers", lambda: ["TensorrtExecutionProvider", "CPUExecutionProvider"])
    monkeypatch.setattr(session.ort, "InferenceSession", without_tensorrt)
    with caplog.at_level("WARNING", logger="fisheye_infer"):
        auto = Detector(small_export.onnx, threads=1, providers="auto", warmup=False)
    assert auto.info.providers == ("CPUExecutionProvider",)
    assert any(
        "TensorrtExecutionProvider did not start" in r.getMessage() and "libnvinfer" in r.getMessage()
        for r in caplog.records
    )
    with pytest.raises(
        ArtifactError, match="cannot load it with TensorrtExecutionProvider, CPUExecutionProvider .*libnvinfer"
    ):
        Detector(small_export.onnx, threads=1, providers=["TensorrtExecutionProvider", "CPUExecutionProvider"])


def test_decode_threads_nest_and_are_checked(detector: Detector, small_export) -> None:
    """map_images called from a decode thread runs there (no deadlock on a full pool)."""
    nested = list(detector.map_images(lambda i: sum(detector.map_images(lambda j: i * j, range(4))), range(16)))
    assert nested == [6 * i for i in range(16)]
    with pytest.raises(OptionError, match="decode_threads: expected a whole number from 1 to .* got int 0"):
        Detector(small_export.onnx, decode_threads=0)
    with pytest.raises(OptionError, match="threads: expected a whole number from 1 to .* got int 0"):
        Detector(small_export.onnx, threads=0)
