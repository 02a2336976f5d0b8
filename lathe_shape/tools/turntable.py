"""Turntable animations of a lathe, rendered at any angle of the turn (the
library behind ``lathe-turntable``; the poses are in :mod:`.poses`, the
frame files in :mod:`.frames`, the animations in :mod:`.video`).

Three modes:

* ``orbit`` (the default) -- the first sensor moves about the lathe's
  world-space axis (the line through the ``to_world`` origin along the
  transformed local +z). The camera turns by ``-angle``, so for a rigid
  ``to_world`` the lathe is seen from the same sides, in the same order, as
  in ``spin`` mode;
* ``world`` -- the camera and the lathe stay; the environment map, the other
  emitters and every other shape turn by ``-angle`` about the lathe's axis
  (:mod:`.world`), so the lathe turns by ``+angle`` against its
  surroundings with its face to the camera (a label stays in view). For a
  lathe without texture a ``world`` frame at ``a`` shows what the ``orbit``
  frame at ``-a`` shows;
* ``spin`` (``rotate`` is an alias) -- the lathe turns in place: its new
  ``to_world`` is ``to_world @ rotate_z(angle)``. A solid of revolution
  looks the same at every angle of a spin, so this only shows a turn for a
  textured lathe (or a coarse reference mesh under a stock integrator); a
  lathe whose BSDF has no spatially varying texture gets a warning
  (:attr:`Turntable.warnings`).

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
    turntable = Turntable(scene, mode="orbit")
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

from .poses import DEFAULT_MODE, MODE_ALIASES, MODES, orbit_matrix, spin_matrix, world_matrix
from .scenes import lathe_ids, scene_integrator
from .world import WorldTurner, transform_matrix

if TYPE_CHECKING:
    from ..plugin.shape import LatheShape

__all__ = [
    "DEFAULT_MODE",
    "GUIDE_CHANNELS",
    "MODES",
    "Turntable",
    "TurntableError",
    "canonical_mode",
    "is_textured",
    "lathes_in_file_order",
]

#: Channels :meth:`Turntable.render` returns after RGB when guides are on:
#: albedo (3) and normal (3).
GUIDE_CHANNELS = 6


class TurntableError(RuntimeError):
    """A turntable cannot be set up; the message says why."""


def canonical_mode(mode: str | None) -> str:
    """``None`` -> the default mode; an alias -> its mode; checked."""
    mode = DEFAULT_MODE if mode is None else MODE_ALIASES.get(mode, mode)
    if mode not in MODES:
        raise TurntableError(f"unknown turntable mode '{mode}' (expected one of: {', '.join(MODES)})")
    return mode


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


def is_textured(shape: mi.Shape) -> bool:
    """Whether anything in the shape's BSDF varies over the surface: a
    texture (bitmap, checkerboard, ...) reachable through
    ``mi.traverse(bsdf)`` whose ``is_spatially_varying()`` is true. Such a
    lathe changes under a spin; one without cannot (its BSDF and its
    surface are the same at every azimuth)."""
    bsdf = shape.bsdf()
    if bsdf is None:
        return False
    params = mi.traverse(bsdf)
    nodes = {id(params.properties[k][2]): params.properties[k][2] for k in params.keys()}
    return any(isinstance(n, mi.Texture) and n.is_spatially_varying() for n in nodes.values())


def _describe_ids(lathes: Sequence[LatheShape]) -> str:
    return ", ".join(f"'{s.id()}'" if s.id() else "(a lathe without id)" for s in lathes) or "none"


def _pick_lathe(lathes: Sequence[LatheShape], object_id: str | None, mode: str) -> LatheShape | None:
    """The lathe named ``object_id``, else the first one; None only in orbit
    and world modes (the turn is then about the world z axis)."""
    if object_id is not None:
        matches = [s for s in lathes if s.id() == object_id]
        if not matches:
            raise TurntableError(
                f"the scene has no lathe with id '{object_id}' (lathes in the scene: {_describe_ids(lathes)})"
            )
        return matches[0]
    if lathes:
        return lathes[0]
    if mode == "spin":
        raise TurntableError("the scene has no lathe shape to rotate (use --mode orbit to orbit the camera)")
    return None


def _sensor_to_world_key(params: mi.SceneParameters, sensor: mi.Sensor) -> str | None:
    """The ``mi.traverse(scene)`` key of the sensor's own ``to_world`` (not
    that of a child object), or None."""
    keys = [k for k in params.keys() if k.split(".")[-1] == "to_world" and params.properties[k][2] is sensor]
    return min(keys, key=len) if keys else None


def _guide_integrator(integrator: mi.Integrator) -> mi.Integrator:
    """An integrator rendering ``integrator``'s image plus albedo and normal
    guides: ``lathe_path`` and ``lathe_volpath`` render them themselves
    (their ``aovs``, on the exact lathes; RGB variants); any other
    integrator, and those in other variants (their ``aovs`` are RGB), is
    wrapped in Mitsuba's ``aov`` integrator (first-hit guides, on the
    lathes' reference meshes)."""
    from ..plugin.lathe_path import LathePathIntegrator
    from ..plugin.lathe_volpath import LatheVolpathIntegrator

    if isinstance(integrator, (LathePathIntegrator, LatheVolpathIntegrator)) and mi.is_rgb:
        integrator.aovs = ("albedo", "nn")
        return integrator
    return mi.load_dict({"type": "aov", "aovs": "albedo:albedo,nn:sh_normal", "integrator": integrator})


class Turntable:
    """Poses a scene for any angle of the turn and renders it.

    ``mode`` is ``"orbit"`` (move the first sensor about the lathe's axis;
    the default), ``"world"`` (turn everything but the lathe and the
    sensors about it) or ``"spin"`` (turn the lathe ``object_id`` itself).
    ``object_id`` names the lathe; ``None`` picks the first lathe (in the
    order of the XML file ``scene_path`` when given). ``guides`` makes
    :meth:`render` return albedo and normal guides after the RGB channels.
    The original transforms are kept, so :meth:`pose` is absolute:
    ``pose(a)`` gives the same scene whatever was posed before.
    """

    def __init__(
        self,
        scene: mi.Scene,
        mode: str | None = None,
        object_id: str | None = None,
        scene_path: str | os.PathLike | None = None,
        guides: bool = False,
    ) -> None:
        from ..plugin.shape import scene_lathes

        self.scene = scene
        self.mode = canonical_mode(mode)
        #: The scene's integrator (stock ``path`` when it names none).
        self.integrator = scene_integrator(scene)
        self.guides = guides
        self._render_integrator = _guide_integrator(self.integrator) if guides else self.integrator
        lathes = scene_lathes(scene) if scene_path is None else lathes_in_file_order(scene, scene_path)
        #: The lathe that turns (spin) or whose axis the turn is about.
        self.lathe: LatheShape | None = _pick_lathe(lathes, object_id, self.mode)
        self.lathe_to_world = None if self.lathe is None else self.lathe.to_world_matrix.copy()
        if not scene.sensors():
            raise TurntableError("the scene has no sensor")
        self.sensor = scene.sensors()[0]
        #: What the user should know about this turntable (one line each).
        self.warnings: list[str] = []
        self._setup_mode()
        self._angle: float | None = None  # the pose the scene is in

    def _setup_mode(self) -> None:
        """What each mode needs to pose the scene, and its warnings."""
        # The package's integrators (lathe_path, lathe_whitted, lathe_prb)
        # intersect lathes with their own transforms through their
        # geometry(scene) (plugin/scene_geometry.py), so a spun lathe need
        # not rebuild the scene's acceleration structure.
        self._exact = callable(getattr(self.integrator, "geometry", None))
        if self.mode == "spin" and not is_textured(self.lathe):
            self.warnings.append(
                f"lathe {self._label()} has no texture: a solid of revolution looks the same at every "
                "angle of a spin, so the frames will be identical (up to noise and tessellation); "
                "use --mode orbit or --mode world to show it turning"
            )
        elif self.mode == "world":
            # lathe_path traces a scene of the non-lathe shapes: turning
            # them through it spares the full scene's rebuild.
            rest = self.integrator.geometry(self.scene).rest if self._exact else None
            self._world = WorldTurner(self.scene, self.lathe, None if rest is self.scene else rest)
            if self._world.fixed:
                self.warnings.append(
                    "world mode cannot turn " + ", ".join(self._world.fixed)
                    + " (no to_world, vertex positions or position to rotate): it stays fixed"
                )
        elif self.mode == "orbit":
            params = self._params = mi.traverse(self.scene)  # kept: posed every frame
            self._sensor_key = _sensor_to_world_key(params, self.sensor)
            if self._sensor_key is None:
                raise TurntableError(f"the sensor '{self.sensor.class_name()}' has no to_world to orbit")
            self.sensor_to_world = transform_matrix(params[self._sensor_key])

    def _label(self) -> str:
        return f"'{self.object_id}'" if self.object_id else "(without id)"

    @property
    def object_id(self) -> str:
        """Id of the turning (or orbited) lathe; ``""`` when there is none."""
        return "" if self.lathe is None else self.lathe.id()

    def describe(self) -> str:
        """What turns, in words (``lathe 'glass' spins about its axis``)."""
        if self.mode == "spin":
            return f"lathe {self._label()} spins about its axis"
        if self.mode == "world":
            about = f"lathe {self._label()}" if self.lathe is not None else "the world z axis (no lathe)"
            return f"the world turns about {about}, the camera stays"
        if self.lathe is not None:
            return f"camera orbits lathe {self._label()}"
        return "camera orbits the world z axis (no lathe in the scene)"

    def pose(self, angle_deg: float) -> None:
        """Pose the scene at ``angle_deg`` of the turn."""
        if self._angle is not None and self._angle == angle_deg:
            return
        if self.mode == "spin":
            # Stock integrators trace the reference mesh, and every
            # integrator an emitting lathe's: the scene's acceleration
            # structure must then follow it.
            matrix = spin_matrix(self.lathe_to_world, angle_deg)
            if self._exact and self.lathe.emitter() is None:
                self.lathe.set_to_world(matrix, exact_only=True)
            else:
                self.lathe.set_to_world(matrix, self.scene)
        elif self.mode == "world":
            geometry = self.integrator.geometry(self.scene) if self._exact else None
            self._world.turn(world_matrix(self.lathe_to_world, angle_deg))
            if geometry is not None:  # the turn rebuilt lathe_path's scene already
                geometry.accept_moves(self.scene)
        else:
            matrix = orbit_matrix(self.sensor_to_world, self.lathe_to_world, angle_deg)
            params = self._params
            params[self._sensor_key] = mi.AffineTransform4f(matrix.astype(np.float32))
            params.update()
        self._angle = angle_deg

    def render(self, angle_deg: float, spp: int | None = None, seed: int = 0) -> np.ndarray:
        """Pose the scene at ``angle_deg`` and render it with the first
        sensor (``spp`` None: the sensor's sampler count): (H, W, 3) linear
        RGB float32, or (H, W, 9) with the albedo and normal guides after
        RGB when the turntable has ``guides``."""
        self.pose(angle_deg)
        image = mi.render(self.scene, spp=spp or 0, seed=seed, sensor=self.sensor,
                          integrator=self._render_integrator)
        pixels = np.asarray(image.numpy(), dtype=np.float32)
        if not self.guides:
            return pixels[..., :3]
        # RGB, then (A), then the guides: mi.render appends AOVs last.
        return np.concatenate([pixels[..., :3], pixels[..., -GUIDE_CHANNELS:]], axis=-1)
