"""The log-polar-like warp (SPEC section 2) and the plain resize of the "w/o log-polar" ablation."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from apr.foveation import foveate, logpolar_grid, logpolar_warp, logpolar_warp_torch, resize

CORNER = math.log(1.0 + math.sqrt(2.0))  # ~0.881


def closed_form(u: float, v: float) -> tuple[float, float]:
    scale = math.log(math.sqrt(u * u + v * v) + 1.0)
    return scale * u, scale * v


def test_grid_matches_the_formula() -> None:
    n = 64
    grid = logpolar_grid(n)
    assert grid.shape == (n, n, 2)
    axis = np.linspace(-1.0, 1.0, n)
    # grid[row, col] = (u', v'): u runs along the columns (x), v along the rows (y).
    for row, col in [(0, 0), (0, n - 1), (n - 1, 0), (n - 1, n - 1), (31, 32), (10, 40), (50, 5), (63, 20)]:
        np.testing.assert_allclose(grid[row, col], closed_form(axis[col], axis[row]), atol=1e-12)
    np.testing.assert_allclose(grid[0, 0], [-CORNER, -CORNER], atol=1e-12)
    np.testing.assert_allclose(grid[0, -1], [CORNER, -CORNER], atol=1e-12)
    assert abs(CORNER - 0.8814) < 1e-4
    assert np.abs(grid).max() == pytest.approx(CORNER)
    assert not grid.flags.writeable


def test_grid_magnifies_the_centre_and_compresses_the_edge() -> None:
    n = 64
    grid = logpolar_grid(n)
    middle = grid[n // 2, :, 0]  # u' along the middle row
    spacing = np.diff(middle)
    uniform = 2.0 / (n - 1)  # a plain resize's spacing in the same coordinates
    assert np.all(spacing > 0), "the warp must keep the order of the pixels"
    assert spacing[n // 2 - 1] < 0.1 * spacing[0]
    assert spacing[n // 2 - 1] < 0.1 * uniform  # centre: finer than one output pixel per input span
    assert spacing[0] > uniform  # edge: coarser


def test_warp_enlarges_a_small_centred_square() -> None:
    image = np.zeros((256, 256), np.uint8)
    image[120:136, 120:136] = 255  # 16x16 pixels: 4x4 after a plain resize
    resized_area = (resize(image, 64) > 127).sum()
    warped_area = (logpolar_warp(image, 64) > 127).sum()
    assert resized_area == 16
    assert warped_area > 8 * resized_area


def test_warp_keeps_the_image_orientation() -> None:
    rows, cols = np.mgrid[0:256, 0:256].astype(np.float32)
    x_ramp, y_ramp = logpolar_warp(cols, 64), logpolar_warp(rows, 64)
    assert np.all(np.diff(x_ramp, axis=1) > 0), "u must run along the columns, left to right"
    assert np.all(np.diff(y_ramp, axis=0) > 0), "v must run along the rows, top to bottom"
    # The centre stays the centre: the four middle output pixels sample within a pixel of the input's centre.
    assert np.abs(x_ramp[31:33, 31:33] - 127.5).max() < 1.0
    assert np.abs(y_ramp[31:33, 31:33] - 127.5).max() < 1.0


def test_numpy_and_torch_warps_agree() -> None:
    rng = np.random.default_rng(0)
    image = rng.random((256, 256, 3), dtype=np.float32)
    flipped = image[::-1].copy()
    batch = torch.from_numpy(np.stack([image, flipped])).permute(0, 3, 1, 2)
    torch_out = logpolar_warp_torch(batch, 64).permute(0, 2, 3, 1).numpy()
    assert torch_out.shape == (2, 64, 64, 3)
    for numpy_out, other in zip((logpolar_warp(image, 64), logpolar_warp(flipped, 64)), torch_out, strict=True):
        assert numpy_out.shape == (64, 64, 3) and numpy_out.dtype == np.float32
        assert np.abs(numpy_out - other).max() < 1e-3
    assert np.abs(torch_out[0] - torch_out[1]).max() > 0.1  # the two images of the batch stay apart


def test_uint8_warp_rounds_the_float_warp() -> None:
    rng = np.random.default_rng(1)
    image = rng.integers(0, 256, (256, 256, 4), dtype=np.uint8)
    warped = logpolar_warp(image, 64)
    assert warped.dtype == np.uint8 and warped.shape == (64, 64, 4)
    exact = logpolar_warp(image.astype(np.float32), 64)
    assert np.abs(warped.astype(np.float32) - exact).max() <= 0.5 + 1e-3


@pytest.mark.parametrize("dtype", [np.uint8, np.float32])
@pytest.mark.parametrize("name", ["logpolar", "resize"])
def test_constant_image_stays_constant(name, dtype) -> None:
    image = np.full((256, 256, 3), 173, dtype)
    out = foveate(image, name, 64)
    assert out.shape == (64, 64, 3) and out.dtype == dtype
    np.testing.assert_allclose(out, 173, atol=1e-3)


def test_resize_averages_blocks() -> None:
    rng = np.random.default_rng(2)
    blocks = rng.uniform(0, 1, (64, 64, 2)).astype(np.float32)
    image = np.repeat(np.repeat(blocks, 4, axis=0), 4, axis=1)
    np.testing.assert_allclose(resize(image, 64), blocks, atol=1e-6)
    checker = np.indices((256, 256)).sum(axis=0) % 2 * 2.0
    np.testing.assert_allclose(resize(checker, 64), 1.0)


def test_bad_foveation_and_bad_shapes_raise() -> None:
    image = np.zeros((256, 256, 3), np.uint8)
    with pytest.raises(ValueError, match=r"foveation must be one of \('logpolar', 'resize'\)"):
        foveate(image, "polar", 64)
    with pytest.raises(ValueError, match="square"):
        logpolar_warp(np.zeros((256, 128, 3)), 64)
    with pytest.raises(ValueError, match="multiple"):
        resize(np.zeros((250, 250, 3)), 64)
