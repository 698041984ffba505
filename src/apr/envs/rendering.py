"""Renderer choice and cameras: pybullet's TinyRenderer, or its EGL plugin.

EGL renders on the GPU where there is one, or through Mesa's llvmpipe on a CPU machine (there, the
environments step 1.56 times as fast as with TinyRenderer: docs/benchmarks.md). The environments' default is
``"tiny"``, which any number of worlds of one process share (a Gymnasium user's ``check_env``, ``SyncVectorEnv``
and two environments in a notebook work as with any environment); the trainer's workers, each a process with
one environment, ask for ``"auto"``, and the run records what it resolved to.

**One renderer per process.** pybullet's EGL plugin serves one physics client per process (its GL context and
renderer state are process-wide: a second client's images take the first one's shadow maps, and disconnecting
one crashes the other's next render). So a process holds at most one EGL world at a time, and ``"auto"``
never mixes renderers within a process: it resolves once, to EGL when the plugin loads (else TinyRenderer for
the rest of the process), and a second "auto" world while an EGL world is open is refused with the ways out
(close the first, ``renderer="tiny"`` for every world of the process, or one process per environment). Two
"auto" environments of one process therefore always see the same images for one seed. ``"tiny"`` is always
honoured; ``"egl"`` raises where EGL cannot serve.

**Fork safety.** Mesa's llvmpipe keeps threads and locks that a forked child inherits without their threads:
the child's first EGL render then waits forever. An "auto" world loads the plugin only at its first render, so
a parent that merely builds environments (``gymnasium.vector.AsyncVectorEnv`` builds one to read the spaces)
stays clean and its forked children render with EGL. A child forked from a process that did load EGL refuses
EGL at once, naming the fixes (``context="spawn"`` or ``renderer="tiny"``).
"""

from __future__ import annotations

import importlib.util
import os
import weakref
from dataclasses import dataclass

import numpy as np
import pybullet as p
from pybullet_utils.bullet_client import BulletClient

from apr.quiet import quiet_c_output

RENDERERS = ("auto", "egl", "tiny")
ONE_PROCESS_EACH = "gymnasium.vector.AsyncVectorEnv(env_fns, context='spawn')"
"""How to give every environment its own process (and its own EGL)."""
EGL_INSTALL = "install Mesa's EGL on a CPU machine (Debian: apt-get install libegl1 libegl-mesa0 libgl1-mesa-dri)"
"""How to make pybullet's EGL plugin load where it does not."""


@dataclass
class _ProcessRenderer:
    """What this process has decided about rendering."""

    pid: int
    holder_ref: weakref.ref | None = None
    """The world that holds the process's EGL renderer (claimed at construction, loaded at its first render);
    a world dropped without being closed lets go of it."""
    auto: str | None = None
    """What "auto" resolved to in this process, once known: "egl" or "tiny"."""
    egl_loaded: bool = False
    """The EGL plugin has been loaded in this process."""
    forked_after_egl: bool = False
    """This process was forked from one that had loaded EGL (an EGL render here would hang)."""


_state = _ProcessRenderer(pid=os.getpid())


def _process() -> _ProcessRenderer:
    """This process's rendering state; a forked child starts afresh, knowing whether its parent loaded EGL."""
    global _state
    if _state.pid != os.getpid():
        _state = _ProcessRenderer(
            pid=os.getpid(), auto="tiny" if _state.auto == "tiny" else None,
            forked_after_egl=_state.egl_loaded or _state.forked_after_egl,
        )  # fmt: skip
    return _state


def egl_holder() -> object | None:
    """The world of this process that holds its EGL renderer, if any."""
    state = _process()
    return state.holder_ref() if state.holder_ref is not None else None


def claim_renderer(world: object, renderer: str) -> str:
    """The renderer a new world will use, "egl" or "tiny"; an EGL world holds the process's EGL renderer until
    :func:`release`. Raises RuntimeError where the request cannot be served without mixing renderers."""
    if renderer not in RENDERERS:
        raise ValueError(f"renderer must be one of {RENDERERS}, got {renderer!r}")
    if renderer == "tiny":
        return "tiny"
    state = _process()
    if renderer == "auto" and state.auto == "tiny":
        return "tiny"
    if state.forked_after_egl:
        raise RuntimeError(
            f"renderer={renderer!r}: this process was forked from one that had loaded pybullet's EGL renderer, and "
            "EGL hangs in such a child (Mesa's threads do not survive fork). Start environment processes with "
            f"'spawn' ({ONE_PROCESS_EACH}, or multiprocessing.get_context('spawn')), or use renderer='tiny'."
        )
    if egl_holder() is not None:
        raise RuntimeError(
            f"renderer={renderer!r}: this process already has an EGL world open, and pybullet's EGL serves one "
            "world per process (a second EGL world would corrupt the first one's renderer; one with TinyRenderer "
            "would see different images for the same seed). Close the first, give every environment of this "
            "process renderer='tiny', or give each "
            f"environment its own process ({ONE_PROCESS_EACH}, or gymnasium.make_vec(..., "
            "vectorization_mode='async', vector_kwargs={'context': 'spawn'}))."
        )
    if importlib.util.find_spec("eglRenderer") is None:
        return _unavailable(renderer, "pybullet's eglRenderer module is missing")
    state.holder_ref = weakref.ref(world)
    return "egl"


def load_egl(world: object, client: BulletClient, renderer: str) -> bool:
    """Load the EGL plugin into ``client`` for ``world`` (which claimed it); False when it does not load and
    ``renderer`` is "auto" (the world then renders with TinyRenderer, as will every "auto" world after it)."""
    state = _process()
    spec = importlib.util.find_spec("eglRenderer")
    with quiet_c_output():
        plugin = client.loadPlugin(spec.origin, "_eglRendererPlugin") if spec and spec.origin else -1
    if plugin < 0:
        if egl_holder() is world:
            state.holder_ref = None
        _unavailable(renderer, "pybullet's EGL plugin did not load")
        return False
    state.egl_loaded = True
    state.auto = "egl"
    return True


def _unavailable(renderer: str, why: str) -> str:
    """EGL cannot serve: raise for "egl"; for "auto", TinyRenderer from now on in this process."""
    if renderer == "egl":
        raise RuntimeError(
            f"renderer='egl' was asked for but {why}. To render with EGL, {EGL_INSTALL}; or use renderer='tiny'."
        )
    _process().auto = "tiny"
    return "tiny"


class _Probe:
    """Stands in for a world in :func:`resolve` (weakly referenced while it holds EGL)."""


def resolve(renderer: str) -> str:
    """What a world of this process asking for ``renderer`` gets now, "egl" or "tiny". For "auto" and "egl" it
    loads pybullet's EGL plugin into a throwaway client to find out (so "auto" is settled for this process, and
    a process forked from this one afterwards refuses EGL); raises where :func:`claim_renderer` would."""
    if renderer not in RENDERERS:
        raise ValueError(f"renderer must be one of {RENDERERS}, got {renderer!r}")
    if renderer == "tiny":
        return "tiny"
    probe = _Probe()
    with quiet_c_output():
        client = BulletClient(connection_mode=p.DIRECT)
    try:
        chosen = claim_renderer(probe, renderer)
        if chosen == "egl" and not load_egl(probe, client, renderer):
            chosen = "tiny"
        return chosen
    finally:
        release(probe, client)


def release(world: object, client: BulletClient) -> None:
    """Disconnect ``client``; if ``world`` held the process's EGL renderer, another world may take it."""
    with quiet_c_output():
        client.disconnect()
    if egl_holder() is world:
        _process().holder_ref = None


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
    if renderer == "egl":
        with quiet_c_output():  # the EGL plugin prints "ven = ..." on renders
            _, _, rgba, _, seg = client.getCameraImage(
                size, size, camera.view_matrix(), projection, renderer=p.ER_BULLET_HARDWARE_OPENGL, flags=flags
            )
    else:
        _, _, rgba, _, seg = client.getCameraImage(
            size, size, camera.view_matrix(), projection, renderer=p.ER_TINY_RENDERER, flags=flags
        )
    rgb = np.asarray(rgba, dtype=np.uint8).reshape(size, size, 4)[..., :3]
    mask = np.asarray(seg, dtype=np.int32).reshape(size, size) if segmentation else None
    return rgb, mask
