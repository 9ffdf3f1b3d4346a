"""Options checked where they enter the Detector, frames as any iterable, and metadata that
contradicts the graph refused at load: on the reduced export in real ONNX Runtime."""

from __future__ import annotations

import json
from contextlib import ExitStack as DoesNotRaise
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fisheye_infer.cameras.rig import default_rig
from fisheye_infer.errors import ArtifactError, FrameError, OptionError
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.runtime.nms import NmsConfig
from fisheye_infer.scenes.render import Renderer, random_scene, resized_rig


@pytest.fixture(scope="module")
def detector(small_export) -> Detector:
    return Detector(small_export.onnx, threads=1)


@pytest.fixture(scope="module")
def frame() -> dict[str, np.ndarray]:
    return Renderer(texture_seed=2).render(resized_rig(default_rig(), 0.2), random_scene(np.random.default_rng(1)))


@pytest.mark.parametrize(
    "options, expectation",
    [
        ({"score_threshold": 0.0}, DoesNotRaise()),
        ({"score_threshold": np.float32(0.5)}, DoesNotRaise()),  # numpy scalars are numbers
        ({"score_threshold": 1}, DoesNotRaise()),
        (
            {"score_threshold": float("nan")},
            pytest.raises(OptionError, match=r"score_threshold: expected a number in \[0, 1\], got nan"),
        ),
        ({"score_threshold": 2.0}, pytest.raises(OptionError, match="got 2.0")),  # silently no boxes before
        ({"score_threshold": -0.1}, pytest.raises(OptionError, match="got -0.1")),
        (
            {"score_threshold": "abc"},
            pytest.raises(OptionError, match="got str 'abc'"),
        ),  # numpy's UFuncTypeError before
        ({"score_threshold": True}, pytest.raises(OptionError, match="got bool")),
        ({"nms": "rotated"}, DoesNotRaise()),  # a kind's name stands for its defaults
        ({"nms": NmsConfig(kind="circle")}, DoesNotRaise()),
        (
            {"nms": "square"},
            pytest.raises(
                OptionError, match="nms: expected an NmsConfig or one of 'rotated', 'circle', got str 'square'"
            ),
        ),
        ({"nms": 0.5}, pytest.raises(OptionError, match="nms: .* got float 0.5")),
        ({"classes": ["Car"]}, DoesNotRaise()),
        ({"classes": ("Car", "Bus")}, DoesNotRaise()),
        (
            {"classes": "Car"},
            pytest.raises(
                OptionError, match=r"classes: got the single string 'Car'; pass a list of class names, e.g. \['Car'\]"
            ),
        ),
        ({"classes": [3]}, pytest.raises(OptionError, match="classes: expected class names")),
        (
            {"classes": ["Dragon"]},
            pytest.raises(OptionError, match="classes: unknown 'Dragon'; the model's classes are Car"),
        ),
        (
            {"classes": [f"c{i}" for i in range(1000)]},
            pytest.raises(OptionError, match="and 980 more"),
        ),  # the message stays short
    ],
)
def test_detect_options_are_checked_at_the_boundary(
    detector: Detector, frame, options: dict[str, Any], expectation
) -> None:
    with expectation:
        detector.detect(frame, **options)


@pytest.mark.parametrize("options", [{"score_threshold": 1.5}, {"nms": "rotated-bev"}, {"spin": "false"}])
def test_detector_options_are_checked_at_construction(small_export, options: dict[str, Any]) -> None:
    with pytest.raises(OptionError):
        Detector(small_export.onnx, threads=1, warmup=False, **options)


def test_a_generator_of_frames_just_works(detector: Detector, frame) -> None:
    listed = detector.detect_batch([frame, frame])
    generated = detector.detect_batch(f for f in (frame, frame))
    assert len(generated) == 2
    np.testing.assert_array_equal(generated[1].scores, listed[1].scores)
    with pytest.raises(FrameError, match="frames: expected a non-empty sequence"):
        detector.detect_batch(f for f in ())
    with pytest.raises(FrameError, match="for one frame use detect"):
        detector.detect_batch(frame)  # one frame (a mapping) where frames were expected


def _edited(source: Path, out: Path, **changes: Any) -> Path:
    onnx = pytest.importorskip("onnx")
    model = onnx.load(str(source))
    for prop in model.metadata_props:
        if prop.key == "fisheye_infer":
            prop.value = json.dumps({**json.loads(prop.value), **changes})
    onnx.save(model, str(out))
    return out


@pytest.mark.parametrize(
    "changes, words",
    [
        ({"num_boxes": 5}, "num_boxes: metadata says 5, the graph's 'boxes' output has 50"),
        ({"classes": ["Car"]}, "classes: metadata lists 1 (Car), the graph returned label"),
    ],
)
def test_metadata_contradicting_the_graph_is_refused_at_load(
    small_export, tmp_path: Path, changes: dict[str, Any], words: str
) -> None:
    edited = _edited(small_export.onnx, tmp_path / "edited.onnx", **changes)
    with pytest.raises(ArtifactError) as err:
        Detector(edited, threads=1)
    assert words in str(err.value)


def test_spin_false_reaches_the_session_and_changes_no_number(
    small_export, frame, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``spin=False`` sets ONNX Runtime's ``session.intra_op.allow_spinning`` to 0 (its threads sleep after a call);
    the default leaves ONNX Runtime's own behaviour (spinning). Two threads, so that there is a pool to spin;
    the boxes are the same either way."""
    import fisheye_infer.runtime.session as session

    real, seen = session.ort.InferenceSession, []

    def recording(path, options, providers, enable_fallback):  # type: ignore[no-untyped-def]
        try:
            seen.append(options.get_session_config_entry("session.intra_op.allow_spinning"))
        except RuntimeError:  # ONNX Runtime raises for an entry never set
            seen.append(None)
        return real(path, options, providers=providers, enable_fallback=enable_fallback)

    monkeypatch.setattr(session.ort, "InferenceSession", recording)
    calm = Detector(small_export.onnx, threads=2, spin=False)
    spinning = Detector(small_export.onnx, threads=2)
    assert seen == ["0", None]
    a, b = spinning.detect(frame), calm.detect(frame)
    np.testing.assert_array_equal(a.boxes, b.boxes)
    np.testing.assert_array_equal(a.scores, b.scores)
