"""ServiceSettings: FISHEYE_* variables, safe defaults, and unsafe combinations refused by name."""

from __future__ import annotations

from contextlib import ExitStack as DoesNotRaise
from typing import Any

import pytest
from pydantic import ValidationError

from fisheye_infer.service.settings import ServiceSettings


def test_defaults_listen_on_loopback_without_microbatching() -> None:
    s = ServiceSettings(model_path="m.onnx")
    assert (s.host, s.port, s.api_key, s.microbatching, s.cors_origins) == ("127.0.0.1", 8000, None, False, [])
    assert s.session_providers is None  # the Detector's default: CPU
    assert s.spin  # ONNX Runtime's default


def test_spin_off_from_the_environment_reaches_the_session_the_service_opens(
    small_export, monkeypatch: pytest.MonkeyPatch
) -> None:
    import anyio

    import fisheye_infer.runtime.session as session
    from fisheye_infer.service.state import Service

    real, seen = session.ort.InferenceSession, []

    def recording(path, options, providers, enable_fallback):  # type: ignore[no-untyped-def]
        seen.append(options.get_session_config_entry("session.intra_op.allow_spinning"))
        return real(path, options, providers=providers, enable_fallback=enable_fallback)

    monkeypatch.setenv("FISHEYE_SPIN", "false")
    settings = ServiceSettings(model_path=small_export.onnx, threads=2, warmup=False)
    assert settings.spin is False
    monkeypatch.setattr(session.ort, "InferenceSession", recording)
    service = Service(settings)
    anyio.run(service.start)
    anyio.run(service.stop)
    assert seen == ["0"]


@pytest.mark.parametrize(
    "value, providers",
    [
        ("CPUExecutionProvider", ["CPUExecutionProvider"]),
        ("auto", "auto"),
        ('["auto"]', "auto"),
        ('["CPUExecutionProvider"]', ["CPUExecutionProvider"]),
        (
            '[["CPUExecutionProvider", {"use_arena": "1", "n": 2}]]',
            [("CPUExecutionProvider", {"use_arena": "1", "n": 2})],
        ),
    ],
)
def test_providers_from_the_environment(monkeypatch: pytest.MonkeyPatch, value: str, providers: object) -> None:
    monkeypatch.setenv("FISHEYE_PROVIDERS", value)
    assert ServiceSettings(model_path="m.onnx").session_providers == providers


def test_environment_with_prefix(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FISHEYE_MODEL_PATH", "/models/model.onnx")
    monkeypatch.setenv("FISHEYE_QUEUE_SIZE", "16")
    monkeypatch.setenv("FISHEYE_API_KEY", "s3cret-s3cret-s3cret")
    monkeypatch.setenv("FISHEYE_CORS_ORIGINS", "https://a.example,https://b.example")
    s = ServiceSettings()
    assert str(s.model_path) == "/models/model.onnx" and s.queue_size == 16
    assert s.api_key is not None and s.api_key.get_secret_value() == "s3cret-s3cret-s3cret"
    assert "s3cret" not in repr(s)  # never printed
    assert s.cors_origins == ["https://a.example", "https://b.example"]


@pytest.mark.parametrize(
    "overrides, expectation",
    [
        ({"microbatch_max_size": 4, "max_batch_frames": 8}, DoesNotRaise()),  # micro-batches fit a batch
        ({"api_key": "short"}, pytest.raises(ValidationError, match="api_key: expected at least 16 characters, got 5")),
        (
            {"microbatch_max_size": 9},
            pytest.raises(ValidationError, match="microbatch_max_size: 9 exceeds max_batch_frames 8"),
        ),
        (
            {"cors_origins": ["*"], "api_key": "k" * 16},
            pytest.raises(ValidationError, match="cors_origins"),
        ),  # any page could use the key
        ({"queue_size": 0}, pytest.raises(ValidationError, match="queue_size")),
        ({"port": 70000}, pytest.raises(ValidationError, match="port")),
        # refused before the model loads, naming what the installed onnxruntime offers
        (
            {"providers": "CUDAExecutionProviderX,CPUExecutionProvider"},
            pytest.raises(
                ValidationError,
                match=r"providers: CUDAExecutionProviderX not offered by the installed onnxruntime \(available: .*CPUExecutionProvider",
            ),
        ),
        (
            {"providers": '[["CUDAExecutionProviderX", {"device_id": 1}]]'},
            pytest.raises(ValidationError, match="CUDAExecutionProviderX not offered"),
        ),
        ({"providers": "auto,CPUExecutionProvider"}, pytest.raises(ValidationError, match="'auto' stands alone")),
    ],
)
def test_unsafe_combinations_are_refused(overrides: dict[str, Any], expectation) -> None:
    with expectation:
        ServiceSettings(model_path="m.onnx", **overrides)
