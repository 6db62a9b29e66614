"""Offscreen MuJoCo rendering of a world, with a lazily created renderer.

On machines without a GPU set ``MUJOCO_GL=osmesa`` (Debian ``libosmesa6``) or ``egl`` *before*
``mujoco`` is first imported; :mod:`pipe_env` defaults it to ``osmesa`` when unset and no display
is present. The renderer is created on first use, after the model exists and inside whichever
process renders (so it is never pickled into subprocess workers).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import mujoco
import numpy as np
from numpy.typing import NDArray

if TYPE_CHECKING:
    from pipe_env.world import PipeWorld


class WorldRenderer:
    """Renders RGB images of a :class:`~pipe_env.world.PipeWorld` from preset or free cameras.

    Args:
        world: the world to render.
        width, height: image size in pixels.
    """

    def __init__(self, world: PipeWorld, width: int = 640, height: int = 480) -> None:
        if width <= 0 or height <= 0:
            raise ValueError(f"render size must be positive, got {width}x{height}")
        self.world = world
        self.width, self.height = int(width), int(height)
        self._renderer: mujoco.Renderer | None = None

    @property
    def renderer(self) -> mujoco.Renderer:
        if self._renderer is None:
            model = self.world.model
            model.vis.global_.offwidth = max(model.vis.global_.offwidth, self.width)
            model.vis.global_.offheight = max(model.vis.global_.offheight, self.height)
            self._renderer = mujoco.Renderer(model, self.height, self.width)
        return self._renderer

    def camera(
        self, view: str = "iso", target: NDArray | None = None, distance: float | None = None
    ) -> mujoco.MjvCamera:
        """A free camera: ``view`` is ``"top"``, ``"side"`` or ``"iso"``, looking at ``target``."""
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
        return cam

    def render(
        self,
        camera: mujoco.MjvCamera | str = "iso",
        markers: list[tuple[NDArray[np.float64], float]] = (),
    ) -> NDArray[np.uint8]:
        """An (height, width, 3) uint8 image of the current state, with optional red sphere
        ``markers`` given as (position m, radius m)."""
        cam = self.camera(camera) if isinstance(camera, str) else camera
        r = self.renderer
        opt = mujoco.MjvOption()
        opt.geomgroup[:] = 1
        opt.geomgroup[self.world.contact_group] = 0
        r.update_scene(self.world.data, camera=cam, scene_option=opt)
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
        return r.render().copy()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_renderer"] = None
        return state


def save_image(image: NDArray[np.uint8], filename: str) -> None:
    """Write an RGB image to PNG with matplotlib."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    plt.imsave(filename, image)
