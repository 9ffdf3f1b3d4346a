"""Pillow's BICUBIC resize reproduced bit for bit: the int64 reference against Pillow, the float32
evaluation against the reference, and the torch pass and its ONNX graph against both."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fisheye_infer.geometry.resize import (
    FLOAT32_EXACT_LIMIT,
    RESIZE_BLOCK,
    ResizeTaps,
    apply_blocks_float32,
    pil_bicubic_taps,
    pil_horizontal_first,
    resize_reference,
)

Image = pytest.importorskip("PIL.Image")
PIL = pytest.importorskip("PIL")
PILLOW_CHOOSES_ORDER = int(PIL.__version__.split(".")[0]) >= 13  # Pillow 13 may run the vertical pass first

WIDTH, HEIGHT = 1280, 720
OUT_WIDTH, OUT_HEIGHT = 800, 450
CROP = (50, 400)  # rows 50..449 of the 800x450 image


def _noise(h: int, w: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _checkerboard(h: int, w: int) -> np.ndarray:
    board = ((np.arange(h)[:, None] // 2 + np.arange(w)[None, :] // 3) % 2) * 255
    return np.repeat(board.astype(np.uint8)[..., None], 3, axis=2)


def _stripes(h: int, w: int) -> np.ndarray:
    image = np.zeros((h, w, 3), dtype=np.uint8)
    image[:, 7::9, 0] = 255  # one-pixel vertical lines: the kernel's lobes overshoot 255 and undershoot 0
    image[5::11, :, 1] = 255
    image[:, (np.arange(w) // 4) % 2 == 1, 2] = 255
    return image


def _gradient(h: int, w: int) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w]
    return np.stack([x * 255 // max(w - 1, 1), y * 255 // max(h - 1, 1), (x + y) % 256], axis=2).astype(np.uint8)


IMAGES = {"noise": _noise, "checkerboard": _checkerboard, "stripes": _stripes, "gradient": _gradient}


@pytest.fixture(scope="module", params=sorted(IMAGES))
def camera_image(request: pytest.FixtureRequest) -> np.ndarray:
    return IMAGES[request.param](HEIGHT, WIDTH)


def pillow(image: np.ndarray, width: int, height: int, *, default_filter: bool = False) -> np.ndarray:
    pil = Image.fromarray(image, "RGB")
    return np.asarray(pil.resize((width, height)) if default_filter else pil.resize((width, height), Image.BICUBIC))


def reference(image: np.ndarray, width: int, height: int, rows: tuple[int, int] | None = None) -> np.ndarray:
    """The reference in the pass order of the installed Pillow."""
    h, w = image.shape[:2]
    first = pil_horizontal_first(w, h, width, height) if PILLOW_CHOOSES_ORDER else True
    return resize_reference(image, width, height, rows, horizontal_first=first)


def float32_resize(
    image: np.ndarray, width: int, height: int, rows: tuple[int, int] | None = None, block: int = RESIZE_BLOCK
) -> np.ndarray:
    first, count = rows if rows is not None else (0, height)
    horizontal = pil_bicubic_taps(image.shape[1], width).blocks(block)
    vertical = pil_bicubic_taps(image.shape[0], height, first, count).blocks(block)
    return apply_blocks_float32(apply_blocks_float32(image.astype(np.float32), horizontal, 1), vertical, 0)


# ---------------------------------------------------------------------------------------------- tables


def test_camera_downscale_taps_fit_float32() -> None:
    taps = pil_bicubic_taps(WIDTH, OUT_WIDTH)
    assert taps.taps == 9  # ceil(2 * 1.6) * 2 + 1
    assert 255 * 2048 * taps.taps < FLOAT32_EXACT_LIMIT
    assert FLOAT32_EXACT_LIMIT > 255 * 2048 * 32  # the split's bound for any Pillow table up to 32 taps
    assert pil_bicubic_taps(HEIGHT, OUT_HEIGHT).taps == 9


@pytest.mark.parametrize(
    "in_size, out_size, first, count", [(1280, 800, 0, None), (720, 450, 50, 400), (7, 23, 0, None), (5, 1, 0, None)]
)
def test_taps_split_and_indices(in_size: int, out_size: int, first: int, count: int | None) -> None:
    taps = pil_bicubic_taps(in_size, out_size, first, count)
    assert taps.index.dtype == np.int64 and taps.coefficients.dtype == np.int64
    assert taps.size == (count or out_size)
    assert taps.index.min() >= 0 and taps.index.max() < in_size
    # Pillow's weights are normalised: each output's coefficients add up to 2**22, up to rounding
    assert np.abs(taps.coefficients.sum(axis=0) - 2**22).max() <= taps.taps


def test_crop_taps_are_the_full_tables_columns() -> None:
    full, crop = pil_bicubic_taps(HEIGHT, OUT_HEIGHT), pil_bicubic_taps(HEIGHT, OUT_HEIGHT, *CROP)
    np.testing.assert_array_equal(crop.coefficients, full.coefficients[:, 50:450])
    np.testing.assert_array_equal(crop.index, full.index[:, 50:450])


def _dense(taps: ResizeTaps) -> np.ndarray:
    """The (out, in) integer matrix of the tap-by-tap tables."""
    matrix = np.zeros((taps.size, int(taps.index.max()) + 1), np.int64)
    np.add.at(matrix, (np.broadcast_to(np.arange(taps.size), taps.index.shape), taps.index), taps.coefficients)
    return matrix


@pytest.mark.parametrize("block", [1, 3, RESIZE_BLOCK, 64])
@pytest.mark.parametrize(
    "in_size, out_size, first, count", [(1280, 800, 0, None), (720, 450, 50, 400), (7, 23, 0, None), (5, 1, 0, None)]
)
def test_blocks_hold_the_same_coefficients(
    in_size: int, out_size: int, first: int, count: int | None, block: int
) -> None:
    taps = pil_bicubic_taps(in_size, out_size, first, count)
    blocks = taps.blocks(block)
    groups = -(-taps.size // block)
    assert blocks.size == taps.size and blocks.index.shape[0] == groups
    assert blocks.high.shape == blocks.low.shape == (groups, block, blocks.index.shape[1])
    assert blocks.index.dtype == np.int64 and blocks.high.dtype == blocks.low.dtype == np.float32
    assert blocks.index.min() >= 0 and blocks.index.max() < in_size
    high, low = blocks.high.astype(np.float64) * 2048, blocks.low.astype(np.float64) * 2048
    np.testing.assert_array_equal(high, np.round(high))  # exact multiples of 1/2048
    np.testing.assert_array_equal(low, np.round(low))
    assert low.min() >= 0 and low.max() < 2048
    matrix = np.zeros((groups * block, int(taps.index.max()) + 1), np.int64)
    rows = np.arange(groups * block).reshape(groups, block, 1)
    columns = np.broadcast_to(blocks.index[:, None, :], blocks.high.shape)
    np.add.at(matrix, (np.broadcast_to(rows, blocks.high.shape), columns), (high * 2048 + low).astype(np.int64))
    np.testing.assert_array_equal(matrix[: taps.size], _dense(taps))
    assert not matrix[taps.size :].any()  # the last block's padding outputs read nothing


def test_block_windows_span_only_contributing_inputs() -> None:
    taps = pil_bicubic_taps(WIDTH, OUT_WIDTH)
    blocks = taps.blocks()
    weights = (blocks.high != 0) | (blocks.low != 0)
    reads = weights.any(axis=1)  # (G, L): the window positions some output of the block reads
    assert reads[:, 0].all() and reads[:, -1].any()
    # ten outputs 1.6 input pixels apart, each reading 2 * 3.2 pixels around its centre
    assert blocks.index.shape[1] <= math.ceil(9 * 1.6 + 2 * 3.2) + 1


@pytest.mark.parametrize(
    "in_size, out_size, first, count", [(0, 5, 0, None), (5, 0, 0, None), (10, 5, 3, 3), (10, 5, -1, 2)]
)
def test_taps_refuse_bad_sizes(in_size: int, out_size: int, first: int, count: int | None) -> None:
    with pytest.raises(ValueError):
        pil_bicubic_taps(in_size, out_size, first, count)


# ------------------------------------------------------------------------------- reference vs Pillow


def test_reference_equals_pillow(camera_image: np.ndarray) -> None:
    expected = pillow(camera_image, OUT_WIDTH, OUT_HEIGHT)
    np.testing.assert_array_equal(resize_reference(camera_image, OUT_WIDTH, OUT_HEIGHT), expected)


def test_default_filter_is_bicubic(camera_image: np.ndarray) -> None:
    """The official pipelines call ``resize((800, 450))`` without a filter."""
    np.testing.assert_array_equal(
        pillow(camera_image, OUT_WIDTH, OUT_HEIGHT, default_filter=True), pillow(camera_image, OUT_WIDTH, OUT_HEIGHT)
    )


def test_reference_crop_equals_pillow_rows(camera_image: np.ndarray) -> None:
    expected = pillow(camera_image, OUT_WIDTH, OUT_HEIGHT)[50:450]
    np.testing.assert_array_equal(resize_reference(camera_image, OUT_WIDTH, OUT_HEIGHT, CROP), expected)


def test_stripes_reach_both_clipping_bounds() -> None:
    """The sharp images are there to exercise Pillow's clip at 0 and 255: check they do."""
    image = _stripes(HEIGHT, WIDTH)
    taps = pil_bicubic_taps(WIDTH, OUT_WIDTH)
    raw = sum(image[:, index, :].astype(np.int64) * k[None, :, None] for index, k in zip(taps.index, taps.coefficients))
    assert raw.min() < 0 and (raw + 2**21 >> 22).max() > 255


SIZES = [
    # (in_w, in_h, out_w, out_h)
    (99, 63, 33, 21),  # downscale by 3
    (125, 75, 25, 15),  # by 5
    (77, 49, 11, 7),  # by 7
    (101, 67, 40, 29),  # non-integer factors
    (37, 23, 101, 67),  # upscale
    (64, 48, 64, 20),  # one axis unchanged (Pillow skips that pass)
    (60, 90, 58, 30),  # Pillow 13 runs the vertical pass first here
    (1, 1, 5, 3),
    (7, 5, 1, 1),
    (1, 9, 4, 1),
    (9, 1, 1, 4),
    (2, 2, 1, 1),
]


@pytest.mark.parametrize("in_w, in_h, out_w, out_h", SIZES)
@pytest.mark.parametrize("kind", sorted(IMAGES))
def test_reference_equals_pillow_other_sizes(kind: str, in_w: int, in_h: int, out_w: int, out_h: int) -> None:
    image = IMAGES[kind](in_h, in_w)
    np.testing.assert_array_equal(reference(image, out_w, out_h), pillow(image, out_w, out_h))


def test_pass_order() -> None:
    assert pil_horizontal_first(WIDTH, HEIGHT, OUT_WIDTH, OUT_HEIGHT)  # the camera resize: the same in every Pillow
    assert pil_horizontal_first(37, 23, 101, 67)
    assert pil_horizontal_first(64, 48, 64, 20)  # Pillow 13 starts vertically, but there is no horizontal pass
    assert not pil_horizontal_first(60, 90, 58, 30)
    image = _noise(90, 60, seed=3)
    horizontal_first = resize_reference(image, 58, 30)
    vertical_first = resize_reference(image, 58, 30, horizontal_first=False)
    assert not np.array_equal(horizontal_first, vertical_first)  # the order is visible in the output
    expected = vertical_first if PILLOW_CHOOSES_ORDER else horizontal_first
    np.testing.assert_array_equal(pillow(image, 58, 30), expected)


# ------------------------------------------------------------------------------ float32 vs reference


def test_float32_equals_reference(camera_image: np.ndarray) -> None:
    expected = resize_reference(camera_image, OUT_WIDTH, OUT_HEIGHT)
    result = float32_resize(camera_image, OUT_WIDTH, OUT_HEIGHT)
    assert result.dtype == np.float32
    np.testing.assert_array_equal(result, expected)
    np.testing.assert_array_equal(float32_resize(camera_image, OUT_WIDTH, OUT_HEIGHT, CROP, block=7), expected[50:450])


@pytest.mark.parametrize("in_w, in_h, out_w, out_h", SIZES)
def test_float32_equals_reference_other_sizes(in_w: int, in_h: int, out_w: int, out_h: int) -> None:
    for kind, make in IMAGES.items():
        image = make(in_h, in_w)
        expected = resize_reference(image, out_w, out_h)
        for block in (1, RESIZE_BLOCK):
            np.testing.assert_array_equal(float32_resize(image, out_w, out_h, block=block), expected, err_msg=kind)


def test_float32_refuses_inexact_tables() -> None:
    """A 1280 -> 1 reduction has 5121 taps: its sums leave float32's exact integers."""
    with pytest.raises(ValueError, match="2\\*\\*24"):
        apply_blocks_float32(np.zeros((1, WIDTH, 3), np.float32), pil_bicubic_taps(WIDTH, 1).blocks(), 1)


# -------------------------------------------------------------------------------------- torch, ONNX


def _camera_batch() -> np.ndarray:
    """B=1, N=2 cameras of 1280x720: noise and the sharp stripes."""
    return np.stack([_noise(HEIGHT, WIDTH, seed=1), _stripes(HEIGHT, WIDTH)])[None]


def _expected(batch: np.ndarray) -> np.ndarray:
    return np.stack([resize_reference(image, OUT_WIDTH, OUT_HEIGHT, CROP) for image in batch[0]])[None].astype(
        np.float32
    )


def _module(block: int = RESIZE_BLOCK) -> Any:
    torch = pytest.importorskip("torch")
    from fisheye_infer.models.resize import pil_resize

    tables = {"h": pil_bicubic_taps(WIDTH, OUT_WIDTH), "v": pil_bicubic_taps(HEIGHT, OUT_HEIGHT, *CROP)}

    class Resize(torch.nn.Module):
        def __init__(self) -> None:
            super().__init__()
            for axis, taps in tables.items():
                blocks = taps.blocks(block)
                for name in ("index", "high", "low"):
                    self.register_buffer(f"{axis}_{name}", torch.from_numpy(getattr(blocks, name)))

        def forward(self, images: torch.Tensor) -> torch.Tensor:
            horizontal, vertical = (self.h_index, self.h_high, self.h_low), (self.v_index, self.v_high, self.v_low)
            return pil_resize(images, horizontal, vertical, (CROP[1], OUT_WIDTH))

    return Resize().eval()


@pytest.fixture(scope="module")
def camera_batch() -> tuple[np.ndarray, np.ndarray]:
    batch = _camera_batch()
    return batch, _expected(batch)


def test_torch_pil_resize_equals_reference(camera_batch: tuple[np.ndarray, np.ndarray]) -> None:
    torch = pytest.importorskip("torch")
    batch, expected = camera_batch
    with torch.no_grad():
        result = _module(block=7)(torch.from_numpy(batch)).numpy()
    assert result.shape == (1, 2, 400, OUT_WIDTH, 3) and result.dtype == np.float32
    np.testing.assert_array_equal(result, expected)


def test_torch_resize_pass_second_to_last_axis() -> None:
    torch = pytest.importorskip("torch")
    from fisheye_infer.models.resize import resize_pass

    image = _checkerboard(45, 61)
    blocks = pil_bicubic_taps(45, 23).blocks(4)  # 6 blocks, the last one padded
    channels_first = torch.from_numpy(np.ascontiguousarray(image.transpose(2, 0, 1)).astype(np.float32))  # (3, H, W)
    tables = (torch.from_numpy(a) for a in (blocks.index, blocks.high, blocks.low))
    result = resize_pass(channels_first, *tables, size=23)
    assert result.shape == (3, 23, 61)
    np.testing.assert_array_equal(
        result.numpy().transpose(1, 2, 0), apply_blocks_float32(image.astype(np.float32), blocks, 0)
    )


ALLOWED_OPS = {"Cast", "Gather", "MatMul", "Mul", "Add", "Floor", "Clip", "Constant", "Transpose", "Reshape"}


def test_onnx_graph_equals_reference(camera_batch: tuple[np.ndarray, np.ndarray], tmp_path: Path) -> None:
    torch = pytest.importorskip("torch")
    onnx = pytest.importorskip("onnx")
    ort = pytest.importorskip("onnxruntime")
    batch, expected = camera_batch
    path = tmp_path / "resize.onnx"
    images = torch.from_numpy(batch)
    torch.onnx.export(
        _module(), (images,), str(path), opset_version=18, dynamo=True, input_names=["images"], output_names=["resized"]
    )

    graph = onnx.load(str(path)).graph
    assert {node.op_type for node in graph.node} <= ALLOWED_OPS
    assert {"Gather", "MatMul", "Floor", "Clip"} <= {node.op_type for node in graph.node}
    float_types = {init.data_type for init in graph.initializer} - {onnx.TensorProto.INT64}
    assert float_types == {onnx.TensorProto.FLOAT}  # no float64 anywhere, integers only as gather indices

    for threads in (1, 2):
        options = ort.SessionOptions()
        options.intra_op_num_threads = threads
        session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
        (result,) = session.run(None, {"images": batch})
        np.testing.assert_array_equal(result, expected, err_msg=f"{threads} threads")
