"""The surface interaction of an exact lathe hit, shared by one lathe's
own query (:meth:`LatheShape.ray_intersect_exact`) and the queries over
many lathes (:mod:`lathe_shape.plugin.scene_geometry`)."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..kernels.common import LatheGeometry, LatheHit

__all__ = ["lathe_interaction"]


def lathe_interaction(ray: mi.Ray3f, hit: LatheHit, geo: LatheGeometry, prim_index: mi.UInt32,
                      shape: mi.ShapePtr) -> mi.SurfaceInteraction3f:
    """A :class:`mitsuba.SurfaceInteraction3f` of the world ray ``ray`` from
    a lathe hit (``t`` in units of ``ray.d``) and its world-space geometry
    ``geo`` (normals already flipped where the lathe's ``flip_normals``
    asks). ``shape`` is the hit lathe (null on misses); misses get ``t =
    inf`` and finite fields."""
    valid = hit.valid
    t = dr.select(valid, hit.t, 0.0)
    si = dr.zeros(mi.SurfaceInteraction3f)
    si.t = dr.select(valid, hit.t, dr.inf)
    si.time = ray.time
    si.wavelengths = ray.wavelengths
    si.p = dr.select(valid, ray(t), 0.0)
    si.n = geo.n
    si.sh_frame = mi.Frame3f(geo.sh_n)
    si.uv = geo.uv
    si.dp_du = geo.dp_du
    si.dp_dv = geo.dp_dv
    si.prim_index = prim_index
    si.shape = shape
    si.wi = dr.select(valid, si.to_local(-ray.d), 0.0)
    return si
