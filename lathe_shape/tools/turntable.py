"""Turntable animations: a lathe spinning about its own axis, or the camera
orbiting it, rendered at any angle of the turn (the library behind
``lathe-turntable``; the poses are in :mod:`.poses`, the frame files in
:mod:`.frames`, the animations in :mod:`.video`).

Two modes:

* ``rotate`` -- the lathe spins in place: its new ``to_world`` is
  ``to_world @ rotate_z(angle)`` (a rotation about its local +z axis);
* ``orbit`` -- the first sensor moves about the lathe's world-space axis (the
  line through the ``to_world`` origin along the transformed local +z). The
  camera turns by ``-angle``, so for a rigid ``to_world`` the lathe is seen
  from the same sides, in the same order, as in ``rotate`` mode.

Every pose is computed from the scene's original transforms (never
accumulated), so frames can be rendered in any order, by any number of
processes, and re-rendering one gives the same image. It is bit-identical
(on the same kind of CPU) when the film's reconstruction filter is ``box``,
or with one Dr.Jit thread (``dr.set_thread_count(1)``); wider filters
(``gaussian``, Mitsuba's default) splat each sample into neighbouring pixels
with atomic adds whose order varies between threads, which changes a few
pixels by float32 rounding (at most about one half-float step in the EXR).

Example::

    import os
    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    import lathe_shape
    from lathe_shape.tools.frames import plan_frames, write_frame
    from lathe_shape.tools.turntable import Turntable

    scene = mi.load_file("scenes/wine_glass.xml", res=128)
    turntable = Turntable(scene, mode="rotate")
    os.makedirs("out", exist_ok=True)
    for frame in plan_frames(24, range(24), "out", seed=0):
        rgb = turntable.render(frame.angle_deg, spp=16, seed=frame.seed)
        write_frame(frame, rgb, {"angle_deg": frame.angle_deg, "seed": frame.seed})
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from typing import TYPE_CHECKING

import mitsuba as mi
import numpy as np

from .poses import orbit_matrix, spin_matrix
from .scenes import lathe_ids, scene_integrator

if TYPE_CHECKING:
    from ..plugin.shape import LatheShape

__all__ = ["MODES", "Turntable", "TurntableError", "lathes_in_file_order"]

#: The two ways of turning: spin the lathe, or orbit the camera about it.
MODES = ("rotate", "orbit")


class TurntableError(RuntimeError):
    """A turntable cannot be set up; the message says why."""


def lathes_in_file_order(scene: mi.Scene, path: str | os.PathLike) -> list[LatheShape]:
    """The scene's lathes (:func:`~lathe_shape.plugin.shape.scene_lathes`) in
    the document order of its XML file ``path``: ``scene.shapes()`` keeps no
    particular order. Lathes are matched to the file's elements by id; those
    without id take the places of the file's elements without id (in the
    scene's order)."""
    # Imported here: the plugin module needs a Mitsuba variant to be set.
    from ..plugin.shape import scene_lathes

    lathes = scene_lathes(scene)
    with open(path, encoding="utf-8") as f:
        names = lathe_ids(f.read(), os.fspath(path))
    rank: dict[str, int] = {}
    for i, name in enumerate(names):
        rank.setdefault(name, i)
    anonymous = iter([i for i, name in enumerate(names) if not name])
    keys = [rank.get(s.id(), len(names)) if s.id() else next(anonymous, len(names)) for s in lathes]
    return [s for _, s in sorted(zip(keys, lathes, strict=True), key=lambda pair: pair[0])]


def _describe_ids(lathes: Sequence[LatheShape]) -> str:
    return ", ".join(f"'{s.id()}'" if s.id() else "(a lathe without id)" for s in lathes) or "none"


def _pick_lathe(lathes: Sequence[LatheShape], object_id: str | None, mode: str) -> LatheShape | None:
    """The lathe named ``object_id``, else the first one; None only in orbit
    mode (the camera then orbits the world z axis)."""
    if object_id is not None:
        matches = [s for s in lathes if s.id() == object_id]
        if not matches:
            raise TurntableError(
                f"the scene has no lathe with id '{object_id}' (lathes in the scene: {_describe_ids(lathes)})"
            )
        return matches[0]
    if lathes:
        return lathes[0]
    if mode == "rotate":
        raise TurntableError("the scene has no lathe shape to rotate (use --orbit to orbit the camera)")
    return None


def _sensor_to_world_key(params: mi.SceneParameters, sensor: mi.Sensor) -> str | None:
    """The ``mi.traverse(scene)`` key of the sensor's own ``to_world`` (not
    that of a child object), or None."""
    keys = [k for k in params.keys() if k.split(".")[-1] == "to_world" and params.properties[k][2] is sensor]
    return min(keys, key=len) if keys else None


def _matrix(transform: object) -> np.ndarray:
    """A Mitsuba (JIT or scalar) transform -> (4, 4) float64."""
    m = np.array(transform.matrix, dtype=np.float64)
    return m.reshape(4, 4) if m.size == 16 else m[..., 0]


class Turntable:
    """Poses a scene for any angle of the turn and renders it.

    ``mode`` is ``"rotate"`` (spin the lathe ``object_id``) or ``"orbit"``
    (move the first sensor about the lathe's axis). ``object_id`` names the
    lathe; ``None`` picks the first lathe (in the order of the XML file
    ``scene_path`` when given). The original transforms are kept, so
    :meth:`pose` is absolute: ``pose(a)`` gives the same scene whatever was
    posed before.
    """

    def __init__(
        self,
        scene: mi.Scene,
        mode: str = "rotate",
        object_id: str | None = None,
        scene_path: str | os.PathLike | None = None,
    ) -> None:
        from ..plugin.shape import scene_lathes

        if mode not in MODES:
            raise TurntableError(f"unknown turntable mode '{mode}' (expected one of: {', '.join(MODES)})")
        self.scene = scene
        self.mode = mode
        #: The scene's integrator (stock ``path`` when it names none).
        self.integrator = scene_integrator(scene)
        lathes = scene_lathes(scene) if scene_path is None else lathes_in_file_order(scene, scene_path)
        #: The lathe that turns (rotate) or whose axis the camera orbits.
        self.lathe: LatheShape | None = _pick_lathe(lathes, object_id, mode)
        self.lathe_to_world = None if self.lathe is None else self.lathe.to_world_matrix.copy()
        if not scene.sensors():
            raise TurntableError("the scene has no sensor")
        self.sensor = scene.sensors()[0]
        self._sensor_key = None
        if mode == "orbit":
            params = mi.traverse(scene)
            self._sensor_key = _sensor_to_world_key(params, self.sensor)
            if self._sensor_key is None:
                raise TurntableError(f"the sensor '{self.sensor.class_name()}' has no to_world to orbit")
            self.sensor_to_world = _matrix(params[self._sensor_key])
        self._angle: float | None = None  # the pose the scene is in

    @property
    def object_id(self) -> str:
        """Id of the turning (or orbited) lathe; ``""`` when there is none."""
        return "" if self.lathe is None else self.lathe.id()

    def pose(self, angle_deg: float) -> None:
        """Pose the scene at ``angle_deg`` of the turn."""
        if self._angle is not None and self._angle == angle_deg:
            return
        if self.mode == "rotate":
            self.lathe.set_to_world(spin_matrix(self.lathe_to_world, angle_deg), self.scene)
        else:
            matrix = orbit_matrix(self.sensor_to_world, self.lathe_to_world, angle_deg)
            params = mi.traverse(self.scene)
            params[self._sensor_key] = mi.AffineTransform4f(matrix.astype(np.float32))
            params.update()
        self._angle = angle_deg

    def render(self, angle_deg: float, spp: int | None = None, seed: int = 0) -> np.ndarray:
        """Pose the scene at ``angle_deg`` and render it with the first
        sensor (``spp`` None: the sensor's sampler count): (H, W, 3) linear
        RGB float32."""
        self.pose(angle_deg)
        image = mi.render(self.scene, spp=spp or 0, seed=seed, sensor=self.sensor,
                          integrator=self.integrator)
        return np.asarray(image.numpy(), dtype=np.float32)[..., :3]
