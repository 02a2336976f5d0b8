"""Ray queries against a scene whose lathes are intersected exactly.

Mitsuba 3.9.1's accelerator cannot call Python intersection code, so the
exact lathes are merged with Mitsuba's own hit here: a second scene holds the
original scene's non-lathe shape objects (the objects are shared, so BSDFs,
area emitters and textures are the same), Mitsuba traces it, and every lathe's
exact kernel is run with the ray's ``maxt`` shortened to that hit. The lathes'
reference triangles are therefore never reported.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .shape import LatheShape, scene_lathes

__all__ = ["ExactSceneGeometry"]


class ExactSceneGeometry:
    """Nearest-hit and shadow-ray queries with every lathe made exact."""

    def __init__(self, scene: mi.Scene) -> None:
        # No reference to the scene itself: it owns the integrator that owns
        # this object (a cycle through C++ references would never be freed).
        self.fingerprint = self.scene_fingerprint(scene)
        shapes = scene.shapes()
        self.lathes: list[LatheShape] = scene_lathes(scene)
        others = [s for s in shapes if not isinstance(s, LatheShape)]
        if any(s.class_name() == "Instance" for s in others):
            self._refuse_instanced_lathes(scene)
        if not self.lathes:
            self.rest = scene
        else:
            description: dict[str, object] = {"type": "scene"}
            ids = [shape.id() for shape in others]
            for index, shape in enumerate(others):
                description[f"shape_{index}"] = shape
            self.rest = mi.load_dict(description)
            # load_dict renames the shared objects after their keys; restore
            # their ids so that mi.traverse(scene) keeps the user's names.
            for shape, name in zip(others, ids, strict=True):
                shape.set_id(name)

    def _refuse_instanced_lathes(self, scene: mi.Scene) -> None:
        """Lathes inside a <shapegroup> are only reached through Mitsuba's
        instances, which cannot call the exact kernel: say so instead of
        silently rendering their reference mesh."""
        direct = {lathe.ptr for lathe in self.lathes}
        params = mi.traverse(scene)
        for key in params.keys():
            node = params.properties[key][2]
            if isinstance(node, LatheShape) and node.ptr not in direct:
                raise RuntimeError(
                    f"lathe_path: lathe '{node.id()}' is inside a <shapegroup>; instanced lathes "
                    "cannot be intersected exactly. Place it in the scene directly (several "
                    "lathes with their own to_world), or render the scene with a stock integrator."
                )

    @staticmethod
    def scene_fingerprint(scene: mi.Scene) -> tuple:
        """Identity and bounds of every shape: changes when the scene is
        another one, or when shapes are moved or edited (mi.traverse)."""
        boxes = ((shape.ptr, shape.bbox()) for shape in scene.shapes())
        return tuple((ptr, tuple(box.min), tuple(box.max)) for ptr, box in boxes)

    def matches(self, scene: mi.Scene) -> bool:
        """Whether this geometry is still valid for ``scene``."""
        return self.fingerprint == self.scene_fingerprint(scene)

    def ray_intersect(self, ray: mi.Ray3f, active: mi.Bool) -> mi.SurfaceInteraction3f:
        """Nearest surface interaction along ``ray`` (``t = inf`` on a miss)."""
        si = self.rest.ray_intersect(ray, ray_flags=mi.RayFlags.All, coherent=False, active=active)
        for lathe in self.lathes:
            ray_lathe = mi.Ray3f(ray)
            ray_lathe.maxt = dr.minimum(ray.maxt, si.t)
            si_lathe = lathe.ray_intersect_exact(ray_lathe, active)
            si = dr.select(si_lathe.t < si.t, si_lathe, si)
        return si

    def ray_test(self, ray: mi.Ray3f, active: mi.Bool) -> mi.Bool:
        """Is anything hit along ``ray`` before ``ray.maxt``?"""
        occluded = self.rest.ray_test(ray, active)
        for lathe in self.lathes:
            occluded |= lathe.ray_test_exact(ray, active & ~occluded)
        return occluded
