"""Surface interactions on lathes that carry derivatives with respect to the
profile points (the ``points`` scene parameter).

:class:`~lathe_shape.plugin.scene_geometry.ExactSceneGeometry` finds the hits
detached; :func:`attach_lathe_hits` re-derives each lathe hit's distance,
position, geometric normal and shading frame from the profile points
(lathe_shape/kernels/attached.py, docs/method.md eqs. 21-25) and grafts
their derivatives onto the detached values (``dr.replace_grad``), so that
every primal value stays the exact kernel's.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..kernels.attached import AttachedHit, attached_bspline, attached_polyline
from ..surfaces import KINDS, kind_of
from .shape import LatheShape

__all__ = ["attach_lathe_hits", "differentiable_kinds", "differentiable_lathes", "lathe_hit"]


def differentiable_kinds() -> tuple[str, ...]:
    """Profile kinds whose hits are attached to their points (their
    records' ``differentiable``, :data:`lathe_shape.surfaces.KINDS`)."""
    return tuple(name for name, kind in KINDS.items() if kind.differentiable)


def _listed(names: tuple[str, ...]) -> str:
    """``a, b and c``."""
    return names[0] if len(names) == 1 else f"{', '.join(names[:-1])} and {names[-1]}"


def lathe_hit(lathe: LatheShape, ray: mi.Ray3f, si: mi.SurfaceInteraction3f, active: mi.Bool) -> AttachedHit:
    """The attached local-frame hit of ``lathe`` for the detached interaction
    ``si`` of the world-space ``ray`` (lanes ``active``)."""
    o = lathe._to_local @ ray.o
    d = lathe._to_local @ ray.d
    t = dr.select(active, si.t, 0.0)
    if kind_of(lathe.surface).kernel == "bspline":
        n_seg = lathe.profile.segment_count
        # The kernel's curve parameter, from uv.y = (seg + u) / n_seg
        u = si.uv.y * n_seg - mi.Float(si.prim_index)
        return attached_bspline(lathe.profile_points, lathe.profile_index, o, d, t,
                                si.prim_index, u, active)
    return attached_polyline(lathe.profile_points, lathe.profile_index, o, d, t,
                             si.prim_index, lathe.smooth, active)


def differentiable_lathes(lathes: list[LatheShape]) -> list[LatheShape]:
    """The lathes whose hits and outlines follow their ``points`` (kinds
    :func:`differentiable_kinds`). The other kinds' hits depend on no
    differentiated parameter; a gradient asked of their points is refused."""
    for lathe in lathes:
        with dr.resume_grad():  # mi.render's primal pass suspends gradients
            asked = dr.grad_enabled(lathe.profile_points)
        if not kind_of(lathe.surface).differentiable and asked:
            raise ValueError(
                f"lathe '{lathe.id()}': gradients with respect to parameter 'points' are available "
                f"for the kinds {_listed(differentiable_kinds())}, not '{lathe.surface.kind}'"
            )
    return [lathe for lathe in lathes if kind_of(lathe.surface).differentiable]


def attach_lathe_hits(lathes: list[LatheShape], ray: mi.Ray3f,
                      si: mi.SurfaceInteraction3f) -> mi.SurfaceInteraction3f:
    """``si`` (detached, from the exact scene geometry) with ``t``, ``p``,
    ``n``, ``sh_frame`` and ``wi`` of its lathe hits attached to the
    profile points; other hits are returned unchanged. Call it where
    gradients are recorded (``dr.resume_grad``)."""
    si = mi.SurfaceInteraction3f(si)
    for lathe in differentiable_lathes(lathes):
        mine = si.is_valid() & (si.shape == mi.ShapePtr(lathe))
        hit = lathe_hit(lathe, ray, si, mine)
        p = lathe._to_world @ mi.Point3f(hit.p)
        n = dr.normalize(lathe._to_world @ mi.Normal3f(hit.n))
        sh_n = dr.normalize(lathe._to_world @ mi.Normal3f(hit.sh_n))
        if lathe.flip:
            n, sh_n = -n, -sh_n
        si.t = dr.select(mine, dr.replace_grad(si.t, hit.t), si.t)
        si.p = dr.select(mine, dr.replace_grad(si.p, p), si.p)
        si.n = dr.select(mine, dr.replace_grad(si.n, n), si.n)
        frame = mi.Frame3f(dr.replace_grad(si.sh_frame.n, sh_n))
        si.sh_frame = dr.select(mine, frame, si.sh_frame)
        si.wi = dr.select(mine, si.to_local(-ray.d), si.wi)
    return si
