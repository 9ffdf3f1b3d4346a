"""The warp as bilinear taps: equal to grid_sample, tables used at the configured size, grid otherwise."""

from __future__ import annotations

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.grids import bilinear_taps, sample_bilinear
from fisheye_infer.geometry.tables import WARP, sampling_tables
from fisheye_infer.models.cylindrical import rectify
from fisheye_infer.models.registry import create_model
from fisheye_infer.models.resample import resample, taps_for


def _grid(h: int, w: int, seed: int) -> np.ndarray:
    """Random coordinates past both edges, plus the edges, the centre and the out-of-view sentinel."""
    g = np.random.default_rng(seed).uniform(-1.3, 1.3, (h, w, 2)).astype(np.float32)
    g[0, :4] = [[-1, -1], [1, 1], [0, 0], [-1, 1]]
    g[1, 0] = [-2.0, -2.0]  # every tap outside (a source of at least 3 x 3)
    return g


def _grid_sample(x: torch.Tensor, grid: np.ndarray) -> torch.Tensor:
    g = torch.from_numpy(grid)[None].expand(x.shape[0], -1, -1, -1)
    return F.grid_sample(x, g, mode="bilinear", padding_mode="zeros", align_corners=True)


@pytest.mark.parametrize(("src", "out"), [((7, 9), (5, 11)), ((50, 50), (25, 100)), ((3, 6), (3, 4))])
def test_resample_equals_grid_sample(src: tuple[int, int], out: tuple[int, int]) -> None:
    grid = _grid(*out, seed=sum(src))
    x = torch.randn(3, 5, *src, generator=torch.Generator().manual_seed(1))
    taps = bilinear_taps(grid, *src)
    got = resample(x, torch.from_numpy(taps.index), torch.from_numpy(taps.weight), out)
    torch.testing.assert_close(got, _grid_sample(x, grid), rtol=0, atol=2e-6)


def test_taps_point_inside_the_source_and_weigh_to_one_inside() -> None:
    grid = _grid(6, 8, seed=3)
    taps = bilinear_taps(grid, 4, 5)
    assert taps.index.dtype == np.int64 and taps.index.shape == (6 * 8 * 4,)
    assert taps.weight.dtype == np.float32 and taps.weight.shape == (6 * 8, 1, 4)
    assert taps.index.min() >= 0 and taps.index.max() < 4 * 5
    inside = (np.abs(grid) <= 1).all(-1).reshape(-1)
    np.testing.assert_allclose(taps.weight[inside, 0].sum(-1), 1.0, atol=1e-6)
    assert (taps.weight[grid.reshape(-1, 2)[:, 0] == -2.0] == 0).all()  # outside: reads 0


def test_numpy_sampling_uses_the_same_taps() -> None:
    grid = _grid(5, 7, seed=4)
    image = np.random.default_rng(5).normal(size=(2, 6, 9)).astype(np.float32)
    expected = _grid_sample(torch.from_numpy(image)[None], grid)[0].numpy()
    np.testing.assert_allclose(sample_bilinear(image, grid), expected, rtol=0, atol=1e-6)


def test_float64_rows_keep_float64() -> None:
    grid = _grid(3, 4, seed=6)
    taps = bilinear_taps(grid, 5, 5)
    x = torch.randn(1, 2, 5, 5, dtype=torch.float64)
    out = resample(x, torch.from_numpy(taps.index), torch.from_numpy(taps.weight), (3, 4))
    assert out.dtype == torch.float64
    torch.testing.assert_close(out, _grid_sample(x, grid.astype(np.float64)), rtol=0, atol=1e-6)


def test_rectify_equals_grid_sample_of_each_camera() -> None:
    images = torch.randint(0, 256, (2, 3, 6, 8, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(2))
    grid = _grid(4, 5, seed=7)
    taps = bilinear_taps(grid, 6, 8)
    got = rectify(images, torch.from_numpy(taps.index), torch.from_numpy(taps.weight), (4, 5))
    per_camera = _grid_sample(images.flatten(0, 1).permute(0, 3, 1, 2).float(), grid)
    torch.testing.assert_close(got, per_camera.reshape(2, 3, 3, 4, 5), rtol=0, atol=1e-4)


def test_tables_at_the_configured_size_grid_otherwise() -> None:
    grid = _grid(3, 4, seed=8)
    tables = {k: torch.from_numpy(v) for k, v in sampling_tables(WARP, grid, (5, 6)).items()}
    index, weight = taps_for(tables, WARP, grid, (5, 6), (5, 6), torch.device("cpu"))
    assert index is tables["geom.warp.index"] and weight is tables["geom.warp.weight"]
    index, weight = taps_for(tables, WARP, grid, (5, 6), (10, 12), torch.device("cpu"))
    expected = bilinear_taps(grid, 10, 12)
    assert np.array_equal(index.numpy(), expected.index) and np.array_equal(weight.numpy(), expected.weight)


def test_tables_need_the_source_size() -> None:
    with pytest.raises(ConfigError, match="source_size"):
        sampling_tables(WARP, _grid(4, 4, seed=0), None)


@pytest.mark.parametrize("arch", ["fisheye-bevdet", "fisheye-petr"])
def test_model_warp_reads_the_tables_at_the_source_size(arch: str) -> None:
    """At the configured input size the warp reads ``geom.warp.*`` from the tables it is given."""
    model = create_model(arch).eval()
    warp = model.view_transform.warp if arch == "fisheye-bevdet" else model.pts_bbox_head.warp
    geometry = model.rig_geometry
    h, w = geometry.params.source_size
    assert (h, w) == (50, 50)  # stride-16 features of the 800 x 800 images
    x = torch.randn(4, 8, h, w, generator=torch.Generator().manual_seed(0))
    x = x if arch == "fisheye-bevdet" else x[None]
    tables = {k: torch.from_numpy(v) for k, v in geometry.sampling_tables().items()}
    base = warp(x, tables)
    official = _grid_sample(x.reshape(-1, 8, h, w), geometry.grid).reshape(base.shape)
    torch.testing.assert_close(base, official, rtol=0, atol=2e-6)
    tables["geom.warp.index"] = tables["geom.warp.index"].roll(4)  # every output pixel reads its neighbour's taps
    assert not torch.allclose(warp(x, tables), base)
