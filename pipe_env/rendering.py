"""Offscreen MuJoCo rendering of a world, with an OpenGL backend chosen on first use.

This module owns the choice of the OpenGL backend and the offscreen renderer. Importing any
pipenav package never sets or needs a GL backend; only the first render picks one
(:func:`gl_backend`):

1. the user's ``MUJOCO_GL`` when it is set (MuJoCo reads it when ``mujoco`` is imported and
   builds its ``mujoco.gl_context.GLContext`` from it; pipenav uses that context as is);
2. otherwise, on Linux, the first of EGL and OSMesa that works: each is tried in a short-lived
   subprocess first, because importing a backend fixes PyOpenGL's platform for the whole
   process (a failed EGL attempt in-process would poison a later OSMesa one); the winner's
   ``mujoco.egl`` / ``mujoco.osmesa`` module is then imported here, lazily;
3. otherwise MuJoCo's default context (GLFW; CGL on macOS), which needs a display.

When nothing works, rendering raises :class:`RenderingUnavailable` saying what to install;
everything that does not render (environments, detector, scenarios, training) is unaffected.
The renderer itself is created on first use, after the model exists and inside whichever process
renders (so it is never pickled into subprocess workers).
"""

from __future__ import annotations

import ctypes.util
import os
import platform
import subprocess
import sys
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import mujoco
import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from pipe_env.world import PipeWorld

#: Background of renders where no geometry is seen (RGB, 0..255): a light grey-blue.
BACKGROUND = np.array([236, 240, 245], dtype=np.uint8)

#: Linux backends tried in order when ``MUJOCO_GL`` is unset: (name, shared library).
_LINUX_CANDIDATES = (("egl", "EGL"), ("osmesa", "OSMesa"))

_PROBE = (
    "import mujoco\n"
    'm = mujoco.MjModel.from_xml_string(\'<mujoco><worldbody><geom size=".1"/></worldbody>'
    "</mujoco>')\n"
    "r = mujoco.Renderer(m, 8, 8)\n"
    "r.update_scene(mujoco.MjData(m))\n"
    "r.render()\n"
    "r.close()\n"
)

_INSTALL_HINT = (
    "Install an OpenGL backend for offscreen rendering: EGL (a GPU driver, or Mesa's "
    "libegl1 on Debian/Ubuntu) or OSMesa (libosmesa6 on Debian/Ubuntu), or set MUJOCO_GL to a "
    "backend that works on this machine (egl, osmesa or glfw with a display). Everything that "
    "does not render keeps working without one."
)


class RenderingUnavailable(RuntimeError):
    """No OpenGL backend works in this process; the message says what was tried and why."""


_chosen: tuple[str, Any] | None = None
_failure: str | None = None


def _probe_in_subprocess(name: str, timeout: float = 60.0) -> str | None:
    """Try backend ``name`` in a fresh interpreter; None if it rendered, else why not."""
    env = {k: v for k, v in os.environ.items() if k != "PYOPENGL_PLATFORM"}
    env["MUJOCO_GL"] = name
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _PROBE],
            env=env,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
    except (OSError, subprocess.TimeoutExpired) as exc:
        return f"trial failed ({exc})"
    if proc.returncode == 0:
        return None
    lines = [ln for ln in proc.stderr.strip().splitlines() if ln.strip()]
    return f"trial render failed ({lines[-1] if lines else f'exit code {proc.returncode}'})"


def _context_class(name: str) -> Any:
    """The ``GLContext`` class of backend ``name`` (imports its module, fixing PyOpenGL's
    platform for this process)."""
    if name == "egl":
        from mujoco.egl import GLContext
    elif name == "osmesa":
        from mujoco.osmesa import GLContext
    else:
        from mujoco.gl_context import GLContext
    return GLContext


def _choose() -> tuple[str, Any]:
    user = os.environ.get("MUJOCO_GL", "").strip().lower()
    if user:
        from mujoco import gl_context

        cls = getattr(gl_context, "GLContext", None)
        if cls is None:
            raise RenderingUnavailable(
                f"MUJOCO_GL={user!r} disables MuJoCo's OpenGL context; rendering needs one. "
                + _INSTALL_HINT
            )
        # tried in a subprocess first: a failed context can leave MuJoCo unable to try again
        failure = _probe_in_subprocess(user)
        if failure is not None:
            raise RenderingUnavailable(f"MUJOCO_GL={user!r}: {failure}. " + _INSTALL_HINT)
        return user, cls
    if platform.system() != "Linux":
        from mujoco.gl_context import GLContext

        return "default", GLContext
    why = []
    forced = os.environ.get("PYOPENGL_PLATFORM", "").strip().lower()
    for name, lib in _LINUX_CANDIDATES:
        if forced and forced != name:
            why.append(f"{name}: PYOPENGL_PLATFORM={forced!r} rules it out")
            continue
        if ctypes.util.find_library(lib) is None:
            why.append(f"{name}: lib{lib} not found")
            continue
        failure = _probe_in_subprocess(name)
        if failure is None:
            try:
                return name, _context_class(name)
            except (ImportError, AttributeError) as exc:  # PyOpenGL already on another platform
                failure = f"works in a fresh process, not in this one ({exc})"
        why.append(f"{name}: {failure}")
    if os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"):
        from mujoco.gl_context import GLContext

        return "glfw", GLContext
    why.append("glfw: no display")
    raise RenderingUnavailable(
        "no OpenGL backend works for offscreen rendering (" + "; ".join(why) + "). " + _INSTALL_HINT
    )


def gl_backend() -> str:
    """The OpenGL backend this process renders with, chosen on the first call (see module
    docstring).

    Raises:
        RenderingUnavailable: when no backend works (the same error on every later call).
    """
    global _chosen, _failure
    if _chosen is None:
        if _failure is not None:
            raise RenderingUnavailable(_failure)
        try:
            _chosen = _choose()
        except RenderingUnavailable as exc:
            _failure = str(exc)
            raise
    return _chosen[0]


def rendering_unavailable_reason() -> str | None:
    """None when rendering works in this process, else the reason (for skips and reports).

    This tries a real context (cheap after the first call), so it is exact."""
    try:
        model = mujoco.MjModel.from_xml_string("<mujoco/>")
        _GLRenderer(model, 8, 8).close()
    except RenderingUnavailable as exc:
        return str(exc)
    return None


class _GLRenderer:
    """An offscreen MuJoCo renderer on the context class :func:`gl_backend` chose (MuJoCo's
    ``mujoco.Renderer`` always uses the class picked when ``mujoco`` was imported)."""

    def __init__(self, model: mujoco.MjModel, height: int, width: int) -> None:
        self.model = model
        self.height, self.width = height, width
        global _failure
        self._gl = self._context(width, height)
        try:
            self._gl.make_current()
            self._con = mujoco.MjrContext(model, mujoco.mjtFontScale.mjFONTSCALE_150.value)
        except Exception as exc:  # noqa: BLE001  (e.g. mujoco.FatalError: no GL loaded)
            self._gl.free()
            _failure = (
                f"the OpenGL backend {_chosen[0] if _chosen else '?'} gives no usable context "
                f"({exc}). " + _INSTALL_HINT
            )
            raise RenderingUnavailable(_failure) from exc
        mujoco.mjr_setBuffer(mujoco.mjtFramebuffer.mjFB_OFFSCREEN.value, self._con)
        self.scene = mujoco.MjvScene(model=model, maxgeom=10000)
        self._rect = mujoco.MjrRect(0, 0, width, height)

    @staticmethod
    def _context(width: int, height: int) -> Any:
        global _failure
        if _failure is not None:  # never retried: a failed attempt can break the next one
            raise RenderingUnavailable(_failure)
        gl_backend()
        assert _chosen is not None
        name, cls = _chosen
        try:
            gl = cls(width, height)
            gl.make_current()
        except Exception as exc:  # noqa: BLE001  (any backend failure is reported the same way)
            _failure = (
                f"the OpenGL backend {name} failed to create a context ({exc}). " + _INSTALL_HINT
            )
            raise RenderingUnavailable(_failure) from exc
        return gl

    def update_scene(
        self, data: mujoco.MjData, camera: mujoco.MjvCamera, scene_option: mujoco.MjvOption
    ) -> None:
        mujoco.mjv_updateScene(
            self.model,
            data,
            scene_option,
            None,
            camera,
            mujoco.mjtCatBit.mjCAT_ALL.value,
            self.scene,
        )

    def render(self) -> NDArray[np.uint8]:
        """The scene as (height, width, 3) uint8 RGB, background pixels set to
        :data:`BACKGROUND`."""
        self._gl.make_current()
        rgb = np.empty((self.height, self.width, 3), dtype=np.uint8)
        mujoco.mjr_render(self._rect, self.scene, self._con)
        mujoco.mjr_readPixels(rgb, None, self._rect, self._con)
        # a second pass in segmentation colours: black where no geom is drawn
        flags = self.scene.flags
        seg_flags = (mujoco.mjtRndFlag.mjRND_SEGMENT, mujoco.mjtRndFlag.mjRND_IDCOLOR)
        saved = [flags[f] for f in seg_flags]
        for f in seg_flags:
            flags[f] = True
        seg = np.empty_like(rgb)
        try:
            mujoco.mjr_render(self._rect, self.scene, self._con)
            mujoco.mjr_readPixels(seg, None, self._rect, self._con)
        finally:
            for f, v in zip(seg_flags, saved):
                flags[f] = v
        rgb[~seg.any(axis=2)] = BACKGROUND
        rgb = rgb[::-1]
        return np.ascontiguousarray(rgb)

    def close(self) -> None:
        if self._gl is not None:
            self._gl.make_current()
            self._con.free()
            self._gl.free()
            self._gl = None


class WorldRenderer:
    """Renders RGB images of a :class:`~pipe_env.world.PipeWorld` from preset or free cameras.

    Args:
        world: the world to render.
        width, height: image size in pixels.

    The OpenGL context is created on the first :meth:`render`, which raises
    :class:`RenderingUnavailable` when no backend works.
    """

    def __init__(self, world: PipeWorld, width: int = 640, height: int = 480) -> None:
        if width <= 0 or height <= 0:
            raise ValueError(f"render size must be positive, got {width}x{height}")
        self.world = world
        self.width, self.height = int(width), int(height)
        self._renderer: _GLRenderer | None = None

    @property
    def renderer(self) -> _GLRenderer:
        if self._renderer is None:
            model = self.world.complete().model  # (a world built without ray meshes: with them)
            model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
            model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
            self._renderer = _GLRenderer(model, self.height, self.width)
        return self._renderer

    def camera(
        self,
        view: str = "iso",
        target: NDArray | None = None,
        distance: float | None = None,
        azimuth: float | None = None,
    ) -> mujoco.MjvCamera:
        """A free camera: ``view`` is ``"top"``, ``"side"`` or ``"iso"``, looking at ``target``
        (m; default the network's centre) from ``distance`` (m; default the whole network),
        optionally turned to ``azimuth`` (degrees)."""
        lo, hi = self.world.network.bounds()
        cam = mujoco.MjvCamera()
        cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        cam.lookat[:] = 0.5 * (lo + hi) if target is None else np.asarray(target, float)
        cam.distance = (
            float(distance) if distance is not None else 1.3 * float(np.max(hi - lo)) + 0.3
        )
        angles = {"top": (-90.0, 90.0), "side": (0.0, 90.0), "iso": (-35.0, 135.0)}
        if view not in angles:
            raise ValueError(f"camera view must be one of {sorted(angles)}, got {view!r}")
        cam.elevation, cam.azimuth = angles[view]
        if azimuth is not None:
            cam.azimuth = float(azimuth)
        return cam

    def render(
        self,
        camera: mujoco.MjvCamera | str = "iso",
        markers: Sequence[tuple[NDArray[np.float64], float]] = (),
    ) -> NDArray[np.uint8]:
        """An (height, width, 3) uint8 image of the current state, with optional red sphere
        ``markers`` given as (position m, radius m).

        Raises:
            RenderingUnavailable: when no OpenGL backend works (see module docstring).
        """
        cam = self.camera(camera) if isinstance(camera, str) else camera
        r = self.renderer
        opt = mujoco.MjvOption()
        opt.geomgroup[:] = 1
        opt.geomgroup[self.world.contact_group] = 0
        # the world with its ray meshes, in this world's state (itself, unless it was built
        # without them: see ``PipeWorld.complete``)
        r.update_scene(self.world.complete().data, camera=cam, scene_option=opt)
        scene = r.scene
        for pos, radius in markers:
            if scene.ngeom >= scene.maxgeom:
                break
            mujoco.mjv_initGeom(
                scene.geoms[scene.ngeom],
                mujoco.mjtGeom.mjGEOM_SPHERE,
                np.array([radius, 0.0, 0.0]),
                np.asarray(pos, dtype=float),
                np.eye(3).ravel(),
                np.array([0.9, 0.15, 0.1, 1.0], dtype=np.float32),
            )
            scene.ngeom += 1
        return r.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_renderer"] = None
        return state


def save_image(image: NDArray[np.uint8], filename: str) -> None:
    """Write an RGB image to PNG with matplotlib (atomically)."""
    import io

    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    from detector.atomic import atomic_write_bytes

    buf = io.BytesIO()
    plt.imsave(buf, image, format="png")
    atomic_write_bytes(filename, buf.getvalue())
