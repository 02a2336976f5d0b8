"""Turning the world about a lathe: the ``world`` mode of a turntable.

The camera and the turning lathe stay where they are; everything else
rotates about the lathe's axis (:func:`~.poses.world_matrix`), found through
``mi.traverse(scene)``:

* shapes with a ``to_world`` (Mitsuba's ``rectangle``, ``sphere``, ``disk``,
  ``cylinder``, ...): the transform is turned (area emitters go with their
  shape);
* meshes (``obj``, ``ply``, ``cube``, ...): their ``vertex_positions`` and
  ``vertex_normals`` are turned;
* other lathes: moved with ``set_to_world``;
* emitters with a ``to_world`` (``envmap``, ``directional``, ``spot``, ...)
  or a ``position`` (``point``): turned or moved.

A ``constant`` emitter looks the same from every direction and needs nothing.
Anything else that exposes none of these parameters cannot be turned: it is
listed by :attr:`WorldTurner.fixed` (the turntable warns once).

Every pose is computed from the values the scene had when the
:class:`WorldTurner` was made, so poses are absolute, never accumulated.
"""

from __future__ import annotations

from dataclasses import dataclass

import mitsuba as mi
import numpy as np

__all__ = ["WorldTurner", "transform_matrix"]

#: Emitters that are invariant under any rotation.
_INVARIANT_EMITTERS = ("ConstantBackgroundEmitter",)


def transform_matrix(transform: object) -> np.ndarray:
    """A Mitsuba (JIT or scalar) transform -> (4, 4) float64."""
    m = np.array(transform.matrix, dtype=np.float64)
    return m.reshape(4, 4) if m.size == 16 else m[..., 0]


@dataclass
class _Turned:
    """One scene parameter that turns with the world and its original value."""

    params: mi.SceneParameters
    key: str
    kind: str  # "to_world", "points", "normals" or "point"
    original: np.ndarray


def _describe(node: object) -> str:
    name = node.id() if hasattr(node, "id") else ""
    return f"{node.class_name()} '{name}'" if name else node.class_name()


class WorldTurner:
    """Turns every emitter and every shape except ``lathe`` (and the sensors)
    about an axis: :meth:`turn` takes the 4x4 rotation of the pose.

    ``shape_scene`` is the scene whose ``mi.traverse`` moves the shapes
    (default: ``scene``). ``lathe_path`` traces its own scene of the
    non-lathe shapes, which shares the shape objects: moving them through
    it rebuilds only that scene's acceleration structure, not the full
    scene's (whose lathe reference meshes make it the costly one). Other
    lathes then move without updating ``scene`` either."""

    def __init__(self, scene: mi.Scene, lathe: mi.Shape | None, shape_scene: mi.Scene | None = None) -> None:
        from ..plugin.shape import LatheShape, scene_lathes

        self.scene = scene
        self._lathe_scene = scene if shape_scene is None else None
        self._shape_scene = shape_scene
        self.params = mi.traverse(scene)
        self.shape_params = self.params if shape_scene is None else mi.traverse(shape_scene)
        self.turned: list[_Turned] = []
        #: Other lathes, with their original ``to_world``.
        self.lathes = [(s, s.to_world_matrix.copy()) for s in scene_lathes(scene) if s is not lathe]
        moved = self._collect(self.params, mi.Emitter, LatheShape)
        moved |= self._collect(self.shape_params, mi.Shape, LatheShape)
        #: Descriptions of the scene objects that cannot be turned.
        self.fixed = self._fixed_objects(moved, LatheShape)

    def _collect(self, params: mi.SceneParameters, kind_of_node: type, lathe_type: type) -> set[int]:
        """Record the turnable parameters of the ``kind_of_node`` objects
        (emitters or shapes) of ``params``; returns the objects' pointers."""
        moved: set[int] = set()
        kinds = {"to_world": "to_world", "vertex_positions": "points", "vertex_normals": "normals",
                 "position": "point"}
        for key in params.keys():
            node = params.properties[key][2]
            kind = kinds.get(key.split(".")[-1])
            if kind is None or not isinstance(node, kind_of_node) or isinstance(node, lathe_type):
                continue
            value = params[key]
            if kind == "to_world":
                original = transform_matrix(value)
            else:
                original = np.array(value, dtype=np.float64).reshape(-1, 3)
            self.turned.append(_Turned(params, key, kind, original))
            moved.add(node.ptr)
        return moved

    def _fixed_objects(self, moved: set[int], lathe_type: type) -> list[str]:
        """Emitters and shapes that exposed nothing to turn."""
        fixed = []
        for emitter in self.scene.emitters():
            if emitter.ptr in moved or emitter.get_shape() is not None:
                continue
            if emitter.class_name() not in _INVARIANT_EMITTERS:
                fixed.append(_describe(emitter))
        for shape in self.scene.shapes():
            if shape.ptr not in moved and not isinstance(shape, lathe_type):
                fixed.append(_describe(shape))
        return fixed

    def turn(self, rotation: np.ndarray) -> None:
        """Pose the world: every turned parameter set to ``rotation`` applied
        to its original value (one ``update()`` per parameter set)."""
        linear = rotation[:3, :3]
        for item in self.turned:
            if item.kind == "to_world":
                item.params[item.key] = mi.AffineTransform4f((rotation @ item.original).astype(np.float32))
                continue
            values = (item.original @ linear.T).astype(np.float32)
            if item.kind != "normals":
                values += rotation[:3, 3].astype(np.float32)
            current = type(item.params[item.key])
            if item.kind == "point":  # a point light's position is one Point3f
                item.params[item.key] = current(*(float(v) for v in values[0]))
            else:  # mesh buffers are flat
                item.params[item.key] = current(values.ravel())
        self.params.update()
        if self.shape_params is not self.params:
            self.shape_params.update()
        for lathe, original in self.lathes:
            if self._lathe_scene is not None:
                lathe.set_to_world(rotation @ original, self._lathe_scene)
            elif lathe.emitter() is not None:
                # Every integrator traces an emitting lathe's mesh: lathe_path
                # in its scene of the non-lathe shapes, which holds it
                lathe.set_to_world(rotation @ original, self._shape_scene)
            else:
                lathe.set_to_world(rotation @ original, exact_only=True)
