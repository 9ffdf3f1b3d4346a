"""The warp as bilinear taps, one set per camera: equal to grid_sample with each camera's grid, tables used at
the configured size, grids otherwise."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.grids import bilinear_taps, sample_bilinear
from fisheye_infer.geometry.tables import RECTIFY, WARP, camera_taps, sampling_tables
from fisheye_infer.models.cylindrical import rectify
from fisheye_infer.models.registry import create_model
from fisheye_infer.models.resample import resample, taps_for


def _grid(h: int, w: int, seed: int) -> np.ndarray:
    """Random coordinates past both edges, plus the edges, the centre and the out-of-view sentinel."""
    g = np.random.default_rng(seed).uniform(-1.3, 1.3, (h, w, 2)).astype(np.float32)
    g[0, :4] = [[-1, -1], [1, 1], [0, 0], [-1, 1]]
    g[1, 0] = [-2.0, -2.0]  # every tap outside (a source of at least 3 x 3)
    return g


def _grids(cameras: int, h: int, w: int, seed: int) -> np.ndarray:
    """(N, H, W, 2): a different grid per camera."""
    return np.stack([_grid(h, w, seed + n) for n in range(cameras)])


def _grid_sample(x: torch.Tensor, grid: np.ndarray) -> torch.Tensor:
    g = torch.from_numpy(grid)[None].expand(x.shape[0], -1, -1, -1)
    return F.grid_sample(x, g, mode="bilinear", padding_mode="zeros", align_corners=True)


def _grid_sample_each(x: torch.Tensor, grids: np.ndarray) -> torch.Tensor:
    """B x N x C x h x w sampled camera by camera with its grid -> B x N x C x H x W."""
    return torch.stack([_grid_sample(x[:, n], grids[n]) for n in range(x.shape[1])], dim=1)


@pytest.mark.parametrize(("src", "out"), [((7, 9), (5, 11)), ((50, 50), (25, 100)), ((3, 6), (3, 4))])
def test_resample_equals_grid_sample_of_each_camera(src: tuple[int, int], out: tuple[int, int]) -> None:
    grids = _grids(3, *out, seed=sum(src))
    x = torch.randn(2, 3, 5, *src, generator=torch.Generator().manual_seed(1))
    taps = camera_taps(grids, *src)
    got = resample(x, torch.from_numpy(taps.index), torch.from_numpy(taps.weight), out)
    torch.testing.assert_close(got, _grid_sample_each(x, grids), rtol=0, atol=2e-6)


def test_taps_point_inside_the_source_and_weigh_to_one_inside() -> None:
    grid = _grid(6, 8, seed=3)
    taps = bilinear_taps(grid, 4, 5)
    assert taps.index.dtype == np.int64 and taps.index.shape == (6 * 8 * 4,)
    assert taps.weight.dtype == np.float32 and taps.weight.shape == (6 * 8, 1, 4)
    assert taps.index.min() >= 0 and taps.index.max() < 4 * 5
    inside = (np.abs(grid) <= 1).all(-1).reshape(-1)
    np.testing.assert_allclose(taps.weight[inside, 0].sum(-1), 1.0, atol=1e-6)
    assert (taps.weight[grid.reshape(-1, 2)[:, 0] == -2.0] == 0).all()  # outside: reads 0


@pytest.mark.parametrize("prefix", [WARP, RECTIFY])
def test_each_camera_reads_its_own_source_rows(prefix: str) -> None:
    grids = _grids(3, 6, 8, seed=9)
    taps = camera_taps(grids, 4, 5, prefix)
    assert taps.index.shape == (3 * 6 * 8 * 4,) and taps.weight.shape == (3 * 6 * 8, 1, 4)
    camera = np.repeat(np.arange(3), 6 * 8 * 4)
    assert (taps.index // (4 * 5) == camera).all()  # camera n's taps lie in its rows n*h*w .. (n+1)*h*w - 1
    second = camera_taps(grids[1:2], 4, 5, prefix)
    np.testing.assert_array_equal(taps.index.reshape(3, -1)[1], second.index + 4 * 5)
    np.testing.assert_array_equal(taps.weight.reshape(3, -1)[1], second.weight.reshape(-1))


def test_taps_need_one_grid_per_camera() -> None:
    with pytest.raises(ConfigError, match=r"\(N, H, W, 2\)"):
        camera_taps(_grid(4, 4, seed=0), 4, 4)


def test_numpy_sampling_uses_the_same_taps() -> None:
    grid = _grid(5, 7, seed=4)
    image = np.random.default_rng(5).normal(size=(2, 6, 9)).astype(np.float32)
    expected = _grid_sample(torch.from_numpy(image)[None], grid)[0].numpy()
    np.testing.assert_allclose(sample_bilinear(image, grid), expected, rtol=0, atol=1e-6)


def test_float64_rows_keep_float64() -> None:
    grids = _grids(2, 3, 4, seed=6)
    taps = camera_taps(grids, 5, 5)
    x = torch.randn(1, 2, 2, 5, 5, dtype=torch.float64)
    out = resample(x, torch.from_numpy(taps.index), torch.from_numpy(taps.weight), (3, 4))
    assert out.dtype == torch.float64
    torch.testing.assert_close(out, _grid_sample_each(x, grids.astype(np.float64)), rtol=0, atol=1e-6)


def test_rectify_equals_grid_sample_of_each_camera() -> None:
    images = torch.randint(0, 256, (2, 3, 6, 8, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(2))
    grids = _grids(3, 4, 5, seed=7)
    taps = camera_taps(grids, 6, 8)
    got = rectify(images, torch.from_numpy(taps.index), torch.from_numpy(taps.weight), (4, 5))
    torch.testing.assert_close(got, _grid_sample_each(images.permute(0, 1, 4, 2, 3).float(), grids), rtol=0, atol=1e-4)


def test_tables_at_the_configured_size_grids_otherwise() -> None:
    grids = _grids(2, 3, 4, seed=8)
    tables = {k: torch.from_numpy(v) for k, v in sampling_tables(WARP, grids, (5, 6)).items()}
    index, weight = taps_for(tables, WARP, grids, (5, 6), (5, 6), torch.device("cpu"))
    assert index is tables["geom.warp.index"] and weight is tables["geom.warp.weight"]
    index, weight = taps_for(tables, WARP, grids, (5, 6), (10, 12), torch.device("cpu"))
    expected = camera_taps(grids, 10, 12)
    assert np.array_equal(index.numpy(), expected.index) and np.array_equal(weight.numpy(), expected.weight)


def test_tables_need_the_source_size() -> None:
    with pytest.raises(ConfigError, match="source_size"):
        sampling_tables(WARP, _grids(1, 4, 4, seed=0), None)


@pytest.mark.parametrize("arch", ["fisheye-bevdet", "fisheye-petr"])
def test_model_warp_reads_the_tables_at_the_source_size(arch: str) -> None:
    """At the configured input size the warp reads ``geom.warp.*`` from the tables it is given."""
    model = create_model(arch).eval()
    warp = model.view_transform.warp if arch == "fisheye-bevdet" else model.pts_bbox_head.warp
    geometry = model.rig_geometry
    h, w = geometry.params.source_size
    assert (h, w) == (50, 50)  # stride-16 features of the 800 x 800 images
    assert geometry.grid.shape[0] == 4
    x = torch.randn(1, 4, 8, h, w, generator=torch.Generator().manual_seed(0))
    tables = {k: torch.from_numpy(v) for k, v in geometry.sampling_tables().items()}
    base = warp(x, tables)
    torch.testing.assert_close(base, _grid_sample_each(x, geometry.grid), rtol=0, atol=2e-6)
    tables["geom.warp.index"] = tables["geom.warp.index"].roll(4)  # every output pixel reads its neighbour's taps
    assert not torch.allclose(warp(x, tables), base)
