"""The path tracer's half of the caustics (eqs. 32 and 40 of
docs/method.md), one piece of code for ``lathe_path`` and
``lathe_volpath``: what a camera path carries to know whether it is a
caustic path the light tracer samples too (:class:`CausticPath`), its
update at each surface vertex (:func:`caustic_vertex`) and the factor an
emitter hit's weight takes (:func:`caustic_emitter_factor`). Both sides of
eq. 40 must apply one rule exactly, so the two integrators share it.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..kernels.common import VariantStruct
from .camera_chain import chain_vertex
from .caustic_paths import CausticTracer, blocks_shadow_rays, caustic_weight, on_lathe, pure_delta
from .deferred_solves import DeferredChainSolves

__all__ = ["CausticPath", "caustic_emitter_factor", "caustic_vertex", "start_caustic_path"]


class CausticPath(metaclass=VariantStruct):
    """Per camera path (eqs. 32 and 40): ``open``, the path so far is
    camera, diffuse ``D``, then Dirac-delta vertices only; ``chain``, those
    vertices after ``D``; ``blocking``, one of them is a vertex that the
    path tracer's shadow rays do not cross (eq. 32's class needs one:
    :func:`~lathe_shape.plugin.caustic_paths.blocks_shadow_rays`);
    ``density``, path tracing's density of it at ``D``; ``camera_chain``,
    the path so far is camera, then Dirac deltas on the camera chain's
    fixed branches; ``camera_d``, its camera ray direction;
    ``camera_branch``, its branch probabilities' product; ``d_through``,
    ``D`` was reached through such a chain, of ``d_vertices`` vertices,
    ``D`` at ``d_p`` with geometric normal ``d_n`` on ``d_shape``."""

    _FIELDS = {"open": "Bool", "chain": "UInt32", "blocking": "Bool", "density": "Float",
               "camera_chain": "Bool", "camera_d": "Vector3f", "camera_branch": "Float", "d_through": "Bool",
               "d_vertices": "UInt32", "d_p": "Point3f", "d_n": "Normal3f", "d_shape": "ShapePtr"}

    def __init__(self, open=None, chain=None, blocking=None, density=None, camera_chain=None, camera_d=None,
                 camera_branch=None, d_through=None, d_vertices=None, d_p=None, d_n=None,
                 d_shape=None) -> None:
        self.open = mi.Bool(False) if open is None else open
        self.chain = mi.UInt32(0) if chain is None else chain
        self.blocking = mi.Bool(False) if blocking is None else blocking
        self.density = mi.Float(0.0) if density is None else density
        self.camera_chain = mi.Bool(True) if camera_chain is None else camera_chain
        self.camera_d = mi.Vector3f(0.0) if camera_d is None else camera_d
        self.camera_branch = mi.Float(1.0) if camera_branch is None else camera_branch
        self.d_through = mi.Bool(False) if d_through is None else d_through
        self.d_vertices = mi.UInt32(0) if d_vertices is None else d_vertices
        self.d_p = mi.Point3f(0.0) if d_p is None else d_p
        self.d_n = mi.Normal3f(0.0) if d_n is None else d_n
        self.d_shape = mi.ShapePtr() if d_shape is None else d_shape


def start_caustic_path(camera_d: mi.Vector3f) -> CausticPath:
    """The state of camera paths whose rays leave along ``camera_d``."""
    return CausticPath(camera_d=mi.Vector3f(camera_d), d_shape=dr.zeros(mi.ShapePtr, dr.width(camera_d)))


@dr.syntax
def caustic_emitter_factor(tracer: CausticTracer, deferred: DeferredChainSolves, per_camera_sample: mi.Float,
                           path: CausticPath, seen: mi.Bool, escaped: mi.Bool, ds: mi.DirectionSample3f,
                           si: mi.SurfaceInteraction3f, ray: mi.Ray3f, ref: mi.Interaction3f,
                           line_point: mi.Point3f, value: mi.Spectrum) -> mi.Float:
    """Eq. 32: the factor on the MIS weight of an emitter hit (lanes
    ``seen``; ``escaped``: the ray ``ray`` left the scene) of a caustic
    path the light tracer samples too, ending on an area light or the
    environment (eq. 35; ``ref``, the previous vertex, ``line_point``, a
    point of the escaping line). Eq. 40: through a camera chain the
    contribution ``value`` is recorded in ``deferred``, solved and added
    after the render kernel (deferred_solves.py), and the factor is 0."""
    factor = mi.Float(1.0)
    # (blocking: a chain of null crossings alone is emitter sampling's too,
    # in lathe_volpath: no caustic path)
    caustic = seen & path.open & path.blocking & (path.chain >= 1) & (path.chain <= tracer.max_chain)
    flags = ds.emitter.flags()
    surface = caustic & mi.has_flag(flags, mi.EmitterFlags.Surface)
    environment = (caustic & escaped & mi.has_flag(flags, mi.EmitterFlags.Infinite)
                   & ~mi.has_flag(flags, mi.EmitterFlags.DeltaDirection))
    both = surface | environment
    # (a symbolic branch: the packets of lanes without such a path skip
    # the densities and the deferral)
    if both:
        p_select, p_area = tracer.light_values(ds.emitter)
        density_surface = tracer.light_density(p_select, p_area, dr.dot(si.sh_frame.n, ray.d), si.p, -ray.d)
        density_environment = tracer.environment_density(
            p_select, ds.emitter.pdf_direction(ref, ds, environment), line_point, ray.d)
        light_density = dr.select(environment, density_environment, density_surface) * per_camera_sample
        # Eq. 40: through a camera chain, the light tracer samples this
        # path only if the solver from D finds this very chain (only where
        # the light sends particles: not a uniform sky)
        defer = both & path.d_through & (light_density > 0.0) & (tracer.chain_share > 0.0)
        limit = tracer.camera_chain_limit(path.chain)
        deferred.record(defer, value, light_density, limit, path.d_p, path.d_n, path.d_shape, path.d_vertices,
                        path.camera_d, path.density * path.camera_branch)
        factor = dr.select(path.d_through, dr.select(defer, 0.0, 1.0),
                           caustic_weight(path.density, light_density))
    return factor


@dr.syntax
def caustic_vertex(tracer: CausticTracer, path: CausticPath, alive: mi.Bool, continues: mi.Bool,
                   count: mi.UInt32, si: mi.SurfaceInteraction3f, bsdf: mi.BSDFPtr, bs: mi.BSDFSample3f,
                   wo_world: mi.Vector3f, cos_in_geo: mi.Float, bad_in: mi.Bool,
                   keeps_chain: mi.Bool) -> CausticPath:
    """``path`` after the surface vertex ``si`` (lanes ``alive``; a lane
    that is not leaves both chains), sampled as ``bs`` towards ``wo_world``
    (world), ``count`` vertices after the camera. Eq. 32: ``D`` is the
    camera ray's first hit (eq. 40: or the first after Dirac deltas on the
    camera chain's branches), smooth, not a lathe, sampled with a smooth
    lobe on the side its shading agrees with, on a lane the path goes on
    from (``continues``); then Dirac deltas only. ``cos_in_geo``, the
    incident direction's cosine with the geometric normal, and ``bad_in``
    (eq. 11 fails on the incident side); ``keeps_chain``: lanes whose
    vertex may stay on a camera chain (eq. 40)."""
    delta_here = pure_delta(bsdf)
    at_d = mi.Bool(False)
    camera_chain, camera_branch, density = path.camera_chain, path.camera_branch, path.density
    d_through, d_vertices = path.d_through, path.d_vertices
    d_p, d_n, d_shape = path.d_p, path.d_n, path.d_shape
    # (a symbolic branch: the packets whose paths all left their camera
    # chain skip it)
    if camera_chain & alive:
        first = count == 0
        at_d = (camera_chain & alive & continues & (count <= tracer.max_chain) & ~bad_in & ~delta_here
                & ~on_lathe(tracer.lathes, si) & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Smooth)
                & (dr.dot(si.n, wo_world) * mi.Frame3f.cos_theta(bs.wo) > 0.0))
        # (through a chain, the camera's part follows at the light)
        density_d = (dr.select(first, tracer.camera.density(si.p, si.n), 1.0) * bs.pdf
                     / dr.maximum(dr.abs(dr.dot(si.n, wo_world)), 1e-12))
        density = dr.select(at_d, density_d, density)
        through_d = at_d & ~first
        d_through = dr.select(at_d, ~first, d_through)
        d_vertices = dr.select(through_d, count, d_vertices)
        d_p = dr.select(through_d, si.p, d_p)
        d_n = dr.select(through_d, si.n, d_n)
        d_shape = dr.select(through_d, si.shape, d_shape)
        camera_chain &= delta_here & ~bad_in & keeps_chain & chain_vertex(si, cos_in_geo, bs, wo_world)
        # (the chain before D only: the deltas after it cancel in eq. 32)
        camera_branch = dr.select(camera_chain, camera_branch * bs.pdf, camera_branch)
    # (the same rule as the light tracer's: blocks_shadow_rays)
    blocking = dr.select(at_d, False,
                         path.blocking | blocks_shadow_rays(bs.sampled_type, tracer.nee_through_null))
    return CausticPath(alive & (at_d | (path.open & delta_here)), dr.select(at_d, 0, path.chain + 1),
                       blocking, density, camera_chain & alive, path.camera_d, camera_branch, d_through,
                       d_vertices, d_p, d_n, d_shape)
