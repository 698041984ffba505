"""The multimodal encoder: GQN's "tower" (Eslami et al. 2018), one view at a time, and r = r1 + r2."""

from __future__ import annotations

from typing import Literal

import torch
import torch.nn.functional as F
from torch import nn


def images_to_float(images: torch.Tensor) -> torch.Tensor:
    """Batched env images to network input.

    Args:
        images: uint8 (B, K, H, W, C), K views in HWC layout as the environment returns them.

    Returns:
        float32 (B, K, C, H, W) in [0, 1]. A permuted view, channels-last in memory, no copy of the layout.
    """
    return images.permute(0, 1, 4, 2, 3).float().div_(255.0)


def tile(vector: torch.Tensor, size: int) -> torch.Tensor:
    """(N, D) -> (N, D, size, size): a vector given spatial extent, as GQN does with the viewpoint."""
    return vector[:, :, None, None].expand(-1, -1, size, size)


def he_init_(module: nn.Module) -> None:
    """Every convolution of ``module``: Kaiming-normal weights for ReLU, fan-in mode (He et al. 2015), zero biases.

    PyTorch's default (Kaiming-uniform with a = sqrt(5), a weight variance of 1 / (3 fan_in)) loses two thirds of
    the signal's variance at each ReLU layer. In the tower the image passes three such layers before the pose is
    concatenated beside it, so at the CPU sizes r then varies about 0.002 between scenes seen from the same
    viewpoints, against 0.24 within a scene: what the images hold reaches r at 1% of its scale, and heads trained
    by Adam read only its constant part (docs/decisions.md, "The encoder's initialisation").
    """
    for layer in module.modules():
        if isinstance(layer, nn.Conv2d):
            nn.init.kaiming_normal_(layer.weight, mode="fan_in", nonlinearity="relu")
            nn.init.zeros_(layer.bias)


class TowerEncoder(nn.Module):
    """GQN's tower: one view (image, pose) -> r_i of shape (R, H/4, W/4).

    conv 2x2/2 -> W; conv 2x2/2 -> W (skip); conv 3x3 -> N; conv 2x2/2 -> W, + skip;
    concatenate the pose tiled over 16x16; conv 3x3 -> W (skip); conv 3x3 -> N; conv 3x3 -> W, + skip;
    conv 1x1 -> R. ReLU after each (paper, Method B; W = 256, N = 128, R = 256). ``init``: "he" (:func:`he_init_`)
    or "torch", PyTorch's default initialisation.
    """

    def __init__(
        self,
        image_channels: int,
        pose_dim: int,
        wide: int = 256,
        narrow: int = 128,
        out: int = 256,
        init: Literal["he", "torch"] = "he",
    ) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(image_channels, wide, kernel_size=2, stride=2)
        self.skip1 = nn.Conv2d(wide, wide, kernel_size=2, stride=2)
        self.conv2 = nn.Conv2d(wide, narrow, kernel_size=3, padding=1)
        self.conv3 = nn.Conv2d(narrow, wide, kernel_size=2, stride=2)
        self.skip2 = nn.Conv2d(wide + pose_dim, wide, kernel_size=3, padding=1)
        self.conv4 = nn.Conv2d(wide + pose_dim, narrow, kernel_size=3, padding=1)
        self.conv5 = nn.Conv2d(narrow, wide, kernel_size=3, padding=1)
        self.conv6 = nn.Conv2d(wide, out, kernel_size=1)
        self.out_channels = out
        if init == "he":
            he_init_(self)
        elif init != "torch":
            raise ValueError(f"init must be 'he' or 'torch', got {init!r}")

    def forward(self, image: torch.Tensor, pose: torch.Tensor) -> torch.Tensor:
        """image: (N, C, 64, 64) in [0, 1]; pose: (N, P) = (v, g). Returns r_i: (N, R, 16, 16)."""
        x = F.relu(self.conv1(image))  # (N, W, 32, 32)
        skip = F.relu(self.skip1(x))  # (N, W, 16, 16)
        x = F.relu(self.conv2(x))  # (N, N', 32, 32)
        x = F.relu(self.conv3(x)) + skip  # (N, W, 16, 16)
        x = torch.cat([x, tile(pose.to(x.dtype), x.shape[-1])], dim=1)  # (N, W + P, 16, 16)
        skip = F.relu(self.skip2(x))
        x = F.relu(self.conv4(x))
        x = F.relu(self.conv5(x)) + skip
        return F.relu(self.conv6(x))  # (N, R, 16, 16)


def encode_scene(encoder: nn.Module, images: torch.Tensor, poses: torch.Tensor) -> torch.Tensor:
    """Sum of the per-view representations (paper, Method B: r = r1 + r2).

    Args:
        encoder: a TowerEncoder (or its compiled wrapper).
        images: float (B, K, C, 64, 64), the K context views.
        poses: (B, K, P), each view's (v, g).

    Returns:
        r: (B, R, 16, 16).
    """
    batch, views = images.shape[:2]
    per_view = encoder(images.flatten(0, 1), poses.flatten(0, 1))  # (B * K, R, 16, 16)
    return per_view.unflatten(0, (batch, views)).sum(dim=1)
