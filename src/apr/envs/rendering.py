"""Renderer choice and cameras: pybullet's EGL plugin when it loads, TinyRenderer otherwise.

EGL renders on the GPU where there is one, or through Mesa's llvmpipe on a CPU machine (there, the
environments step 1.56 times as fast as with TinyRenderer: docs/benchmarks.md). ``renderer="auto"`` tries EGL and
falls back to TinyRenderer.
"""

from __future__ import annotations

import ctypes
import importlib.util
import os
import sys
import warnings
from dataclasses import dataclass

import numpy as np
import pybullet as p
from pybullet_utils.bullet_client import BulletClient

RENDERERS = ("auto", "egl", "tiny")

# pybullet's EGL plugin shares one GL context among all the clients of a process that load it: their shadow
# maps leak into each other's images, and disconnecting one crashes the others' next render. So a process holds
# at most one EGL client at a time; vectorised environments get one each from their own worker processes.
_egl_client: BulletClient | None = None


def load_renderer(client: BulletClient, renderer: str) -> str:
    """Load the renderer named ``renderer`` into ``client``; return the one in use ("egl" or "tiny")."""
    if renderer not in RENDERERS:
        raise ValueError(f"renderer must be one of {RENDERERS}, got {renderer!r}")
    global _egl_client
    if renderer == "tiny":
        return "tiny"
    if _egl_client is not None:
        if renderer == "egl":
            raise RuntimeError(
                "renderer='egl': this process already has an EGL world open (pybullet's EGL plugin shares one GL "
                "context per process). Close it, run each environment in its own process "
                "(gymnasium.vector.AsyncVectorEnv), or use renderer='tiny'."
            )
        warnings.warn(
            "renderer='auto' falls back to TinyRenderer: this process already has an EGL world open "
            "(one per process; AsyncVectorEnv gives each environment its own).",
            stacklevel=5,  # the caller of GraspWorld(...): the env constructor or user code
        )
        return "tiny"
    spec = importlib.util.find_spec("eglRenderer")
    plugin = -1
    if spec is not None and spec.origin is not None:
        with _silenced_stdout():
            plugin = client.loadPlugin(spec.origin, "_eglRendererPlugin")
    if plugin >= 0:
        _egl_client = client
        return "egl"
    if renderer == "egl":
        raise RuntimeError(
            "renderer='egl' was asked for but pybullet's EGL plugin did not load. On a CPU machine install "
            "Mesa's EGL (Debian: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri), or use renderer='tiny'."
        )
    return "tiny"


def release(client: BulletClient) -> None:
    """Disconnect ``client``; once the process's EGL client is released, another world may load EGL."""
    global _egl_client
    client.disconnect()
    if client is _egl_client:
        _egl_client = None


@dataclass(frozen=True)
class Camera:
    """A pinhole camera: where it is, what it looks at, which way is up in the image."""

    eye: np.ndarray
    """(3,) optical centre, world frame (m)."""
    forward: np.ndarray
    """(3,) unit line of sight."""
    up: np.ndarray
    """(3,) unit vector, image up."""
    fov_deg: float

    def view_matrix(self) -> list[float]:
        return p.computeViewMatrix(self.eye.tolist(), (self.eye + self.forward).tolist(), self.up.tolist())

    def sight_error(self, point: np.ndarray) -> float:
        """Distance (m) from ``point`` to the camera's line of sight."""
        offset = np.asarray(point, dtype=np.float64) - self.eye
        return float(np.linalg.norm(offset - np.dot(offset, self.forward) * self.forward))


def render(
    client: BulletClient,
    camera: Camera,
    size: int,
    renderer: str,
    near: float,
    far: float,
    segmentation: bool = False,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Render ``camera``.

    Returns:
        rgb: uint8 (size, size, 3).
        segmentation: int32 (size, size) body ids per pixel (-1 background), or None when not asked for.
    """
    projection = p.computeProjectionMatrixFOV(camera.fov_deg, 1.0, near, far)
    flags = 0 if segmentation else p.ER_NO_SEGMENTATION_MASK
    engine = p.ER_BULLET_HARDWARE_OPENGL if renderer == "egl" else p.ER_TINY_RENDERER
    _, _, rgba, _, seg = client.getCameraImage(
        size, size, camera.view_matrix(), projection, renderer=engine, flags=flags
    )
    rgb = np.asarray(rgba, dtype=np.uint8).reshape(size, size, 4)[..., :3]
    mask = np.asarray(seg, dtype=np.int32).reshape(size, size) if segmentation else None
    return rgb, mask


class _silenced_stdout:
    """Silence the C-level stdout (the EGL plugin prints its GL strings when it loads)."""

    def __enter__(self) -> None:
        _flush_stdout()
        self._saved = os.dup(1)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)
        os.close(devnull)

    def __exit__(self, *exc: object) -> None:
        _flush_stdout()
        os.dup2(self._saved, 1)
        os.close(self._saved)


def _flush_stdout() -> None:
    """Flush Python's and C's stdout buffers, so nothing written before or after lands on the wrong side."""
    sys.stdout.flush()
    ctypes.CDLL(None).fflush(None)
