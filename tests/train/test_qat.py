"""Quantization-aware training: the int8 simulation's grid and scope, and --qat, --workers, --device in a run."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from typing import Any  # noqa: E402

from torch import nn  # noqa: E402

from fisheye_infer.cameras.rig import Rig  # noqa: E402
from fisheye_infer.cli import main  # noqa: E402
from fisheye_infer.errors import ConfigError  # noqa: E402
from fisheye_infer.models import get_model_entry, load_checkpoint  # noqa: E402
from fisheye_infer.models.training.loop import Trainer  # noqa: E402
from fisheye_infer.models.training.options import TrainOptions, training_device  # noqa: E402
from fisheye_infer.models.training.qat import FakeQuant, fake_quant_activation, fake_quant_weight, percentile_range  # noqa: E402
from fisheye_infer.precision import WEIGHT_QMAX  # noqa: E402

Run = Any


def test_weights_land_on_the_int8_files_grid_per_output_channel() -> None:
    w = torch.randn(6, 4, 3, 3) * torch.tensor([1e-3, 0.1, 1.0, 10.0, 3.0, 0.5]).reshape(6, 1, 1, 1)
    q = fake_quant_weight(w, 0, WEIGHT_QMAX[7])
    scale = w.abs().amax(dim=(1, 2, 3), keepdim=True) / 64
    steps = q / scale
    torch.testing.assert_close(steps, steps.round(), rtol=0, atol=1e-4)
    assert steps.abs().amax(dim=(1, 2, 3)).tolist() == pytest.approx(
        [64.0] * 6, abs=1e-4
    )  # each channel uses the whole 7-bit range
    assert ((q - w).abs() <= scale / 2 + 1e-7).all()


def test_a_transposed_convolution_the_export_rewrites_gets_a_scale_per_output_channel_and_kernel_position() -> None:
    torch.manual_seed(0)
    up = nn.ConvTranspose2d(
        8, 4, 2, stride=2, bias=False
    )  # kernel = stride: a 1x1 Conv to 4 x 2 x 2 channels in the file
    with torch.no_grad():
        up.weight[:, 0, 0, 0] *= 20  # one position of one channel much larger: it must not coarsen the others' grid
    fq = FakeQuant(up)
    fq.ranges[""] = (torch.tensor(-10.0), torch.tensor(10.0))
    up.eval()
    x = torch.randn(1, 8, 3, 3)
    captured: list[torch.Tensor] = []
    original = torch.nn.functional.conv_transpose2d
    try:
        torch.nn.functional.conv_transpose2d = lambda inp, w, *a, **k: (captured.append(w), original(inp, w, *a, **k))[
            1
        ]  # type: ignore[assignment]
        up(x)
    finally:
        torch.nn.functional.conv_transpose2d = original
    w, q = up.weight.detach(), captured[0].detach()
    scale = w.abs().amax(dim=0, keepdim=True) / 64  # per (out, k, k)
    torch.testing.assert_close(q / scale, (q / scale).round(), rtol=0, atol=1e-4)
    assert ((q - w).abs() <= scale / 2 + 1e-7).all()


def test_input_ranges_are_onnx_runtimes_percentile_of_the_magnitudes() -> None:
    g = torch.Generator().manual_seed(0)
    relu_like = torch.cat([torch.rand(50_000, generator=g), torch.tensor([1000.0])])
    low, high = percentile_range(relu_like)
    assert float(low) == pytest.approx(float(relu_like.min())) and 0.99 < float(high) < 1.0  # the outlier clipped
    signed = torch.rand(50_000, generator=g) * 4 - 3  # [-3, 1]: the magnitude's percentile is about 3
    low, high = percentile_range(signed)
    assert -3.0 <= float(low) < -2.99 and float(high) == pytest.approx(float(signed.max()))


def test_activations_round_to_u8_with_zero_exact() -> None:
    x = torch.linspace(-1.0, 3.0, 1001)
    q = fake_quant_activation(x, torch.tensor(-1.0), torch.tensor(3.0))
    scale = 4.0 / 255
    assert len(torch.unique(q)) <= 256 and ((q - x).abs() <= scale / 2 + 1e-6).all()
    assert float(fake_quant_activation(torch.zeros(3), torch.tensor(-1.0), torch.tensor(3.0)).abs().max()) == 0.0
    # a range that excludes 0 is widened to hold it (U8 with a zero point)
    assert float(fake_quant_activation(torch.tensor([0.0, 2.0]), torch.tensor(1.0), torch.tensor(2.0))[0]) == 0.0


class _Net(nn.Module):
    def __init__(self) -> None:
        super().__init__()
        self.conv = nn.Conv2d(3, 8, 3, padding=1)
        self.up = nn.ConvTranspose2d(8, 4, 2, stride=2, bias=False)
        self.head = nn.Sequential(nn.Flatten(), nn.Linear(4 * 16 * 16, 5))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.head(self.up(torch.relu(self.conv(x))))


def test_fake_quant_covers_what_the_int8_file_quantizes_and_leaves_the_state_dict_alone() -> None:
    torch.manual_seed(0)
    net, x = _Net(), torch.randn(2, 3, 8, 8)
    keys, plain = list(net.state_dict()), net(x).detach()
    fq = FakeQuant(net, keep_float=("head",))
    assert set(fq.layers) == {"conv", "up"}
    assert list(net.state_dict()) == keys
    simulated = net(x)
    assert not torch.equal(simulated, plain)
    assert float((simulated.detach() - plain).abs().max()) < 0.05 * float(plain.abs().max())
    fq.enabled = False
    assert torch.equal(net(x).detach(), plain)
    fq.enabled = True
    simulated.sum().backward()  # the rounding passes gradients straight through
    assert net.conv.weight.grad is not None and float(net.conv.weight.grad.abs().sum()) > 0
    fq.remove()
    assert "forward" not in vars(net.conv) and torch.equal(net(x).detach(), plain)


def test_input_ranges_follow_training_batches_and_hold_in_eval() -> None:
    torch.manual_seed(0)
    net = _Net()
    fq = FakeQuant(net)
    net.train()
    net(torch.randn(2, 3, 8, 8))
    first = [float(v) for v in fq.ranges["conv"]]
    net(10 * torch.randn(2, 3, 8, 8))
    moved = [float(v) for v in fq.ranges["conv"]]
    assert moved[0] < first[0] and moved[1] > first[1]
    net.eval()
    net(100 * torch.randn(2, 3, 8, 8))
    assert [float(v) for v in fq.ranges["conv"]] == moved


def test_the_detectors_simulated_layers_are_the_int8_files(small_bevdet_config: Any, small_export: Any) -> None:
    import onnx

    from fisheye_infer.cameras.rig import default_rig
    from fisheye_infer.export.int8_scope import WEIGHTED_OPS, int8_nodes, module_of
    from fisheye_infer.models import create_model
    from fisheye_infer.scenes.render import resized_rig

    model = create_model("fisheye-bevdet", small_bevdet_config, resized_rig(default_rig(), 0.2))
    float_modules = get_model_entry("fisheye-bevdet").int8_float
    names = set(FakeQuant(model, float_modules).layers)
    graph = onnx.load(str(small_export.onnx))
    weights = {i.name for i in graph.graph.initializer}
    chosen = set(int8_nodes(graph, "network", float_modules))
    int8_layers = {module_of(n, weights) for n in graph.graph.node if n.name in chosen and n.op_type in WEIGHTED_OPS}
    traced = {module_of(n, weights) for n in graph.graph.node}
    assert {
        "img_backbone.conv1",
        "view_transform.depthnet",
        "bbox_head.shared_conv",
        "pts_neck.deblocks.0.0",
    } <= int8_layers
    assert names & traced == int8_layers  # a layer the trace never reached (an unused FPN level) rounds to no effect
    with pytest.raises(ValueError, match="no module of the model"):
        FakeQuant(model, ("bbox_head.nowhere",))


def test_qat_share_is_checked_and_drawn_per_step(small_bevdet_config: Any, tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="--qat"):
        TrainOptions(qat=1.5)
    from fisheye_infer.cameras.rig import default_rig
    from fisheye_infer.scenes.render import resized_rig

    small_rig = resized_rig(default_rig(), 0.2)
    draws = [Trainer(small_bevdet_config, small_rig, tmp_path / f"r{q}", TrainOptions(qat=q)) for q in (0.0, 0.5, 1.0)]
    assert draws[0].fake_quant is None and not any(draws[0].int8_step(s) for s in range(50))
    half = [draws[1].int8_step(s) for s in range(400)]
    assert half == [draws[1].int8_step(s) for s in range(400)] and 150 < sum(half) < 250
    assert all(draws[2].int8_step(s) for s in range(50))


def test_devices_are_checked() -> None:
    with pytest.raises(ConfigError, match="not a torch device"):
        training_device("gpu")
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="no such CUDA device"):
            training_device("cuda")
    with pytest.raises(ConfigError, match="expected cpu or cuda"):
        training_device("meta")
    assert training_device("cpu").type == "cpu"


@pytest.fixture(scope="module")
def qat_run(tmp_path_factory: pytest.TempPathFactory, straight_run: Run) -> Path:
    """Two int8-simulating steps from the straight run's weights, frames rendered ahead by one worker process."""
    out = tmp_path_factory.mktemp("qat") / "run"
    folder = straight_run.folder
    argv = [
        "train",
        "--out",
        str(out),
        "--init",
        str(folder / "model.pth"),
        "--config",
        str(folder / "config.py"),
        "--rig",
        str(folder / "rig.json"),
        "--steps",
        "2",
        "--batch-size",
        "1",
        "--lr",
        "1e-4",
        "--val-frames",
        "1",
        "--qat",
        "1",
        "--workers",
        "1",
    ]
    assert main(argv) == 0
    return out


def test_a_resumed_qat_run_is_the_uninterrupted_one(straight_run: Run, tmp_path: Path) -> None:
    folder = straight_run.folder
    argv = [
        "--init",
        str(folder / "model.pth"),
        "--config",
        str(folder / "config.py"),
        "--rig",
        str(folder / "rig.json"),
        "--steps",
        "3",
        "--batch-size",
        "1",
        "--lr",
        "1e-4",
        "--val-frames",
        "0",
        "--qat",
        "1",
        "--checkpoint-every",
        "1",
    ]
    assert main(["train", "--out", str(tmp_path / "straight"), *argv]) == 0
    assert main(["train", "--out", str(tmp_path / "parts"), *argv, "--until", "2"]) == 0
    resume = ["--resume", *argv[6:]]
    assert main(["train", "--out", str(tmp_path / "parts"), *resume]) == 0
    a, _ = load_checkpoint(tmp_path / "straight" / "model.pth")
    b, _ = load_checkpoint(tmp_path / "parts" / "model.pth")
    for key in a:
        torch.testing.assert_close(b[key], a[key], rtol=0, atol=0, msg=key)
    ranges = torch.load(tmp_path / "parts" / "checkpoint.pth", weights_only=True)["fake_quant"]
    assert ranges and all(low <= high for low, high in ranges.values())


def test_a_qat_run_trains_rounded_and_saves_a_plain_checkpoint(qat_run: Path, straight_run: Run) -> None:
    rows = [json.loads(line) for line in (qat_run / "log.jsonl").read_text().splitlines()]
    train_rows = [r for r in rows if "split" not in r]
    assert [r["int8"] for r in train_rows] == [True, True] and all(np.isfinite(r["loss"]) for r in rows)
    tuned, meta = load_checkpoint(qat_run / "model.pth")
    start, _ = load_checkpoint(straight_run.folder / "model.pth")
    assert list(tuned) == list(start) and meta["train_options"]["qat"] == 1.0
    assert all(v.device.type == "cpu" for v in tuned.values())


def test_frames_rendered_by_workers_are_the_frames_of_the_loop(straight_run: Run, tmp_path: Path) -> None:
    from fisheye_infer.models import BEVDetConfig

    folder = straight_run.folder
    config, rig = BEVDetConfig.from_mmdet3d_config(folder / "config.py"), Rig.load(folder / "rig.json")
    trainer = Trainer(config, rig, tmp_path / "run", TrainOptions(steps=3, batch_size=2), workers=1)
    ahead = list(trainer._batches(3))
    assert len(ahead) == 3 and trainer._batches(0).num_workers == 0  # nothing to render: no process started
    for step, (samples, depth, _) in enumerate(ahead):
        inline_samples, inline_depth, _ = trainer.train_batches[step]
        assert [s.index for s in samples] == [2 * step, 2 * step + 1] == [s.index for s in inline_samples]
        assert all(np.array_equal(a.images, b.images) for a, b in zip(samples, inline_samples))
        assert np.array_equal(depth, inline_depth)


def test_resuming_below_the_step_reached_is_refused(
    resumed_run: tuple[Run, Run], capsys: pytest.CaptureFixture[str]
) -> None:
    _, resumed = resumed_run
    assert (
        main(
            [
                "train",
                "--out",
                str(resumed.folder),
                "--resume",
                "--steps",
                "3",
                *("--batch-size", "1", "--lr", "1e-3"),
                "--val-frames",
                "1",
                "--checkpoint-every",
                "2",
            ]
        )
        == 1
    )
    err = capsys.readouterr().err
    assert "--steps 3: the run" in err and "already at step 4" in err
