"""Foveation: the paper's log-polar-like warp, and the plain resize of the "w/o log-polar" ablation.

For (u, v) on a regular grid over [-1, 1]^2 (the output image), the warp samples the input image at

    (u', v') = log(sqrt(u^2 + v^2) + 1) * (u, v)                      (paper, Method B)

in the same normalised coordinates, where -1 and +1 are the outer edges of the input image. The centre is
magnified (the sampling spacing tends to zero there) and the periphery compressed; the output covers
|u'| <= log(1 + sqrt(2)) ~= 0.881 of the input. ``u`` runs along the image columns (x), ``v`` along the rows (y).

The grid is computed once per output size and the sampling is bilinear, with the same convention as
``torch.nn.functional.grid_sample(..., align_corners=False)``, so the NumPy path (used by the environments)
and the torch path (used on batches of images) agree to rounding.
"""

from __future__ import annotations

import functools
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import torch

FOVEATIONS = ("logpolar", "resize")


@functools.cache
def logpolar_grid(out_size: int) -> np.ndarray:
    """Sampling coordinates of the log-polar-like warp.

    Returns:
        float64 array of shape (out_size, out_size, 2): ``grid[row, col] = (u', v')`` in [-1, 1] input
        coordinates (x first, as ``grid_sample`` expects). Read-only; cached per size.
    """
    axis = np.linspace(-1.0, 1.0, out_size)
    u, v = np.meshgrid(axis, axis, indexing="xy")  # u varies along columns, v along rows
    scale = np.log(np.sqrt(u**2 + v**2) + 1.0)
    grid = np.stack([scale * u, scale * v], axis=-1)
    grid.setflags(write=False)
    return grid


@functools.cache
def _bilinear_taps(in_size: int, out_size: int) -> tuple[np.ndarray, ...]:
    """Precomputed gather indices and weights of the warp for a square input of ``in_size`` pixels."""
    grid = logpolar_grid(out_size)
    # Normalised [-1, 1] (outer pixel edges) -> pixel centres, the align_corners=False convention.
    pix = ((grid + 1.0) * in_size - 1.0) / 2.0
    x, y = pix[..., 0], pix[..., 1]
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    wx, wy = x - x0, y - y0
    x0c, x1c = np.clip(x0, 0, in_size - 1), np.clip(x0 + 1, 0, in_size - 1)
    y0c, y1c = np.clip(y0, 0, in_size - 1), np.clip(y0 + 1, 0, in_size - 1)
    flat = lambda yy, xx: (yy * in_size + xx).ravel()  # noqa: E731
    indices = np.stack([flat(y0c, x0c), flat(y0c, x1c), flat(y1c, x0c), flat(y1c, x1c)])
    weights = np.stack(
        [((1 - wy) * (1 - wx)).ravel(), ((1 - wy) * wx).ravel(), (wy * (1 - wx)).ravel(), (wy * wx).ravel()]
    ).astype(np.float32)
    return indices, weights


def logpolar_warp(image: np.ndarray, out_size: int = 64) -> np.ndarray:
    """Warp one square image with the log-polar-like grid (bilinear).

    Args:
        image: (H, H, C) or (H, H) array, any real dtype (uint8 images stay uint8, rounded).
        out_size: side of the output image.
    Returns:
        (out_size, out_size, C) or (out_size, out_size) array of ``image``'s dtype.
    """
    height, width = image.shape[:2]
    if height != width:
        raise ValueError(f"logpolar_warp expects a square image, got {height}x{width}")
    indices, weights = _bilinear_taps(height, out_size)
    flat = image.reshape(height * width, -1).astype(np.float32)
    out = np.einsum("kn,knc->nc", weights, flat[indices])
    return _cast_like(out.reshape((out_size, out_size) + image.shape[2:]), image.dtype)


def resize(image: np.ndarray, out_size: int = 64) -> np.ndarray:
    """Plain area-average resize of a square image whose side is a multiple of ``out_size``.

    This is the "w/o log-polar" ablation: the same render, uniformly downsampled.
    """
    height, width = image.shape[:2]
    if height != width or height % out_size:
        raise ValueError(f"resize expects a square image with side a multiple of {out_size}, got {height}x{width}")
    k = height // out_size
    blocks = image.reshape(out_size, k, out_size, k, -1).astype(np.float32).mean(axis=(1, 3))
    return _cast_like(blocks.reshape((out_size, out_size) + image.shape[2:]), image.dtype)


def foveate(image: np.ndarray, foveation: str, out_size: int = 64) -> np.ndarray:
    """Apply the named foveation (``"logpolar"`` or ``"resize"``) to an (H, H, C) image."""
    if foveation == "logpolar":
        return logpolar_warp(image, out_size)
    if foveation == "resize":
        return resize(image, out_size)
    raise ValueError(f"foveation must be one of {FOVEATIONS}, got {foveation!r}")


def logpolar_warp_torch(images: torch.Tensor, out_size: int = 64) -> torch.Tensor:
    """Batched torch version of :func:`logpolar_warp`.

    Args:
        images: float tensor (B, C, H, H).
    Returns:
        float tensor (B, C, out_size, out_size), bilinear samples at the log-polar-like grid.
    """
    import torch
    import torch.nn.functional as F

    # torch.tensor copies: the cached grid is read-only
    grid = torch.tensor(logpolar_grid(out_size), dtype=images.dtype, device=images.device)
    grid = grid.unsqueeze(0).expand(images.shape[0], -1, -1, -1)
    return F.grid_sample(images, grid, mode="bilinear", padding_mode="border", align_corners=False)


def _cast_like(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    if np.issubdtype(dtype, np.integer):
        info = np.iinfo(dtype)
        return np.clip(np.rint(values), info.min, info.max).astype(dtype)
    return values.astype(dtype)
