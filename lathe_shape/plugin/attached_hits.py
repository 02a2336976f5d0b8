"""Surface interactions on lathes that carry derivatives with respect to the
profile points (the ``points`` scene parameter).

:class:`~lathe_shape.plugin.scene_geometry.ExactSceneGeometry` finds the hits
detached; :func:`attach_lathe_hits` re-derives each lathe hit's distance,
position, geometric normal and shading frame from the profile points
(lathe_shape/kernels/attached.py, docs/method.md eqs. 21-25) and grafts
their derivatives onto the detached values (``dr.replace_grad``), so that
every primal value stays the exact kernel's; :func:`attached_direction`
turns a sampled Dirac-delta direction with the attached vertex (eq. 28).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..kernels.attached import AttachedHit, attached_bspline, attached_polyline
from ..surfaces import KINDS, kind_of
from .shape import LatheShape

__all__ = ["attach_lathe_hits", "attached_direction", "differentiable_kinds", "differentiable_lathes",
           "lathe_hit"]


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


def attached_direction(bsdf: mi.BSDFPtr, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f,
                       bs: mi.BSDFSample3f, wo_world: mi.Vector3f, sample_2: mi.Point2f, active: mi.Bool,
                       lobes: tuple[bool, bool], grazing_cosine: float,
                       stored: list | None = None) -> tuple[mi.Vector3f, mi.Spectrum]:
    """The sampled direction ``wo_world`` and a factor of primal value 1
    carrying the derivative of the sample's weight, at the attached vertex
    ``si`` (``bs``: the detached draw). Mitsuba's BSDFs sample detached, so
    a Dirac delta's direction is rebuilt here from the attached incident
    direction and frame (eq. 28: a mirror reflection, or a refraction with
    the sample's relative IOR) and its Fresnel weight from the attached
    angle, the lobe choice held; any other lobe's direction stays put and
    its weight follows the attached BSDF value (eq. 29). Near grazing and
    near the critical angle these derivatives are unbounded and left out
    (eq. 30). ``lobes``: whether the scene has delta lobes, and other
    lobes (:func:`scene_lobes`); ``grazing_cosine``: eq. 30's threshold;
    ``stored``: a list that receives the detached values to evaluate with
    the vertex (None: evaluated here)."""
    has_delta, has_smooth = lobes
    if not has_delta:
        value = bsdf.eval(ctx, si, si.to_local(wo_world), active)
        return wo_world, dr.select(dr.detach(value) == 0.0, 1.0, dr.relative_grad(value))
    delta = active & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
    reflected = mi.has_flag(bs.sampled_type, mi.BSDFFlags.DeltaReflection)
    # The relative IOR of the transmission the lobe choice was made against
    # (for a reflection, from a draw with transmission alone; none: a
    # mirror, or total internal reflection, whose weight is constant)
    only_transmission = mi.BSDFContext()
    only_transmission.type_mask = mi.BSDFFlags.DeltaTransmission
    transmitted, _ = bsdf.sample(only_transmission, dr.detach(si), 0.5, sample_2, delta & reflected)
    # (stored, as the vertex's other detached values)
    if stored is None:
        dr.eval(transmitted)
    else:
        stored.append(transmitted)
    eta_it = dr.select(reflected, transmitted.eta, bs.eta)
    fresnel = delta & dr.select(reflected, transmitted.pdf > 0.0, True) & (eta_it != 1.0)
    wi = si.wi
    cos_i = mi.Frame3f.cos_theta(wi)
    eta_ti = dr.rcp(eta_it)
    cos_t = -dr.mulsign(dr.safe_sqrt(1.0 - dr.square(eta_ti) * (1.0 - dr.square(cos_i))), dr.detach(cos_i))
    wo_local = dr.select(reflected, mi.reflect(wi), mi.refract(wi, cos_t, eta_ti))
    cos_t_detached = dr.abs(dr.detach(cos_t))
    grazing = delta & (dr.abs(dr.detach(cos_i)) < grazing_cosine)
    grazing |= delta & ~reflected & (cos_t_detached < grazing_cosine)
    critical = fresnel & (cos_t_detached < grazing_cosine)
    turned = dr.replace_grad(wo_world, si.to_world(wo_local))
    wo_world = dr.select(delta & ~grazing, turned, wo_world)
    # Eq. 28: F of the interface (IOR inside over outside) at the attached angle
    eta = dr.select(dr.detach(cos_i) > 0.0, eta_it, eta_ti)
    reflectance, _, _, _ = mi.fresnel(cos_i, eta)
    value = mi.Spectrum(dr.select(reflected, reflectance, 1.0 - reflectance))
    if has_smooth:
        value = dr.select(delta, value, bsdf.eval(ctx, si, si.to_local(wo_world), active & ~delta))
    held = grazing | critical | (delta & ~fresnel) | (dr.detach(value) == 0.0)
    return wo_world, dr.select(held, 1.0, dr.relative_grad(value))
