"""The ``lathe_prb`` integrator: differentiable path tracing with exact lathes.

.. list-table::
   :header-rows: 1

   * - Parameter
     - Type
     - Description
   * - ``max_depth``, ``rr_depth``, ``hide_emitters``
     - integer, integer, boolean
     - The path's longest depth (-1 = infinite; default 6), the depth where
       Russian roulette starts (default 5), and whether directly visible
       emitters are hidden (default false), as for ``lathe_path``.
   * - ``normal_check``
     - string
     - The eq. 11 policy where the interpolated shading normal contradicts
       the real surface, as for ``lathe_path``: ``none``, ``terminate`` or
       ``fallback`` (default).
   * - ``silhouette``
     - boolean
     - Add the derivative of the lathes' moving outlines as the camera sees
       them (edge sampling of the exact silhouette,
       :mod:`lathe_shape.plugin.silhouette`). (Default: true)
   * - ``silhouette_spp``
     - integer
     - Camera rays on each side of every outline sample. (Default: 4)

Path Replay Backpropagation (Mitsuba's ``prb``: a primal pass, then a
replay of the same paths that propagates derivatives vertex by vertex) on
the exact lathe geometry of ``lathe_path``: hits come from
:class:`~lathe_shape.plugin.scene_geometry.ExactSceneGeometry` (detached
kernel solves), and each lathe hit is then attached to the lathe's
``points`` parameter by implicit differentiation
(:mod:`lathe_shape.plugin.attached_hits`, docs/method.md eqs. 21-25): its
position, geometric normal and interpolated shading normal carry
derivatives with respect to the profile. BSDF and emitter parameters are
differentiated as ``prb`` does. Use it through ``mi.render(scene, params,
...)`` with ``dr.backward`` or ``dr.forward``.

What is differentiated: everything that varies smoothly with the profile at
a fixed set of visible surfaces (shading, the light's distance and angle,
the solid-angle change of moving vertices: "interior" derivatives). Not
included in that part: the change of *which* surface a ray sees. At the
lathe's outline as the camera sees it, that change is added by edge
sampling of the exact silhouette (``silhouette``, docs/method.md eqs.
26-27); shadow boundaries and outlines seen through other surfaces are
left out (their share is measured in the README, "Differentiable lathes"),
as is the motion of directions through Dirac-delta BSDFs (glass, mirrors),
which ``prb`` omits as well. Non-lathe shapes are not differentiated with
respect to their geometry.

Eq. 11 under differentiation (docs/method.md, eq. 25): each policy's decision
(terminate, use the geometric frame, reject a light sample) is taken on the
detached values and held fixed; the derivative is that of the branch taken.
The decisions change only on a set of measure zero in parameter space, so
this is the derivative almost everywhere of the rendered estimate.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
from mitsuba.ad.integrators.common import RBIntegrator, mis_weight, solid_angle_to_area_jacobian

from .attached_hits import attach_lathe_hits, differentiable_lathes
from .lathe_path import NORMAL_CHECKS, contradicts, with_geometric_frame
from .params import typed_property
from .scene_geometry import ExactSceneGeometry
from .silhouette import outline_backward, outline_forward, outline_samples
from .variants import register_jit_plugin

__all__ = ["LathePRBIntegrator", "register"]


def _sensor(scene: mi.Scene, sensor: int | mi.Sensor) -> mi.Sensor:
    return scene.sensors()[sensor] if isinstance(sensor, int) else sensor


def _moving_wi(lathes, ray_prev: mi.Ray3f, si_prev: mi.SurfaceInteraction3f,
               si: mi.SurfaceInteraction3f, active: mi.Bool) -> mi.Vector3f:
    """``si.wi`` with the derivative of the previous vertex's motion (a
    lathe hit that moves with the profile turns the incident direction)."""
    prev = attach_lathe_hits(lathes, ray_prev, si_prev)
    wi_world = dr.normalize(prev.p - dr.detach(si.p))
    return dr.select(active, dr.replace_grad(si.wi, si.to_local(wi_world)), si.wi)


def _reattach_emitter_sample(scene: mi.Scene, si: mi.SurfaceInteraction3f, ds: mi.DirectionSample3f,
                             em_weight: mi.Spectrum, active: mi.Bool):
    """The detached emitter sample ``ds`` and its weight, re-evaluated with
    derivatives of the (moving) shading point, as ``prb`` does (textured area
    lights apart)."""
    is_surface = mi.has_flag(ds.emitter.flags(), mi.EmitterFlags.Surface)
    is_infinite = mi.has_flag(ds.emitter.flags(), mi.EmitterFlags.Infinite)
    to_light = ds.p - si.p
    ds.d = dr.replace_grad(ds.d, dr.select(is_infinite, ds.d, dr.normalize(to_light)))
    # Point lights fall off with this distance (prb keeps it detached)
    ds.dist = dr.replace_grad(ds.dist, dr.select(is_infinite, ds.dist, dr.norm(to_light)))
    # A moving shading point changes the solid angle of the sampled area
    J = solid_angle_to_area_jacobian(si.p, dr.detach(ds.p), dr.detach(ds.n), active & is_surface)
    em_val = scene.eval_emitter_direction(si, ds, active)
    inv_pdf = dr.select(ds.pdf != 0, dr.rcp(ds.pdf), 0)
    em_weight = dr.replace_grad(em_weight, em_val * dr.detach(inv_pdf)) * dr.relative_grad(J)
    return ds, em_weight


def _resample_geometric(bsdf: mi.BSDF, ctx: mi.BSDFContext, sampler: mi.Sampler, si: mi.SurfaceInteraction3f,
                        redo: mi.Bool, drawn: tuple):
    """The ``fallback`` policy: where ``redo``, the BSDF sample ``drawn`` =
    (sample, weight, world direction) is drawn again in the geometric frame."""
    si_geo = with_geometric_frame(si, redo)
    bs_geo, weight_geo = bsdf.sample(ctx, si_geo, sampler.next_1d(), sampler.next_2d(), redo)
    redrawn = (bs_geo, weight_geo, si_geo.to_world(bs_geo.wo))
    return tuple(dr.select(redo, new, old) for new, old in zip(redrawn, drawn, strict=True))


class LathePRBIntegrator(RBIntegrator):
    """Path Replay Backpropagation with exact, differentiable lathes (see
    the module docstring for the parameters)."""

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        self.normal_check = typed_property(props, "normal_check", str, "fallback", "lathe_prb")
        if self.normal_check not in NORMAL_CHECKS:
            raise ValueError(
                f"lathe_prb: parameter 'normal_check': unknown policy '{self.normal_check}' "
                f"(expected one of: {', '.join(NORMAL_CHECKS)})"
            )
        self.silhouette = typed_property(props, "silhouette", bool, True, "lathe_prb")
        self.silhouette_spp = typed_property(props, "silhouette_spp", int, 4, "lathe_prb")
        if self.silhouette_spp < 1:
            raise ValueError(f"lathe_prb: parameter 'silhouette_spp' must be >= 1, got {self.silhouette_spp}")
        self._geometry = None

    def geometry(self, scene: mi.Scene) -> ExactSceneGeometry:
        """The scene's exact-lathe ray queries (kept while the scene's
        shapes stay the same, as ``lathe_path`` keeps them)."""
        current = ExactSceneGeometry.for_scene(scene, self._geometry)
        self._geometry = current if current.lathes else None
        for lathe in differentiable_lathes(current.lathes):
            # Index maps built here, outside the traced loop (no new
            # buffers inside it)
            lathe.profile_index  # noqa: B018
        return current

    # Built before the render queues its camera rays (see lathe_path.render).
    def render(self, scene: mi.Scene, sensor=0, seed=0, spp=0, develop=True, evaluate=True):
        self.geometry(scene)
        return super().render(scene, sensor, seed, spp, develop, evaluate)

    def render_forward(self, scene: mi.Scene, params, sensor=0, seed=0, spp=0):
        geometry = self.geometry(scene)
        outline = None
        if self.silhouette and geometry.lathes:
            # Before the interior pass, which consumes the parameters' tangents
            outline = outline_forward(self, scene, _sensor(scene, sensor), seed, self.silhouette_spp)
        image = super().render_forward(scene, params, sensor, seed, spp)
        if outline is not None:
            image += mi.TensorXf(outline[..., : image.shape[2]].astype(np.float32))
        return image

    def render_backward(self, scene: mi.Scene, params, grad_in, sensor=0, seed=0, spp=0):
        geometry = self.geometry(scene)
        outline = self.silhouette and bool(geometry.lathes)
        if outline:
            # The outline pieces (numpy: it waits for queued kernels) before
            # the interior pass is queued: that pass's kernel then runs while
            # the outline term is traced
            camera = _sensor(scene, sensor)
            pieces = outline_samples(camera, differentiable_lathes(geometry.lathes))
            grad_image = np.array(grad_in)
        super().render_backward(scene, params, grad_in, sensor, seed, spp)
        if outline:
            outline_backward(self, scene, camera, grad_image, seed, self.silhouette_spp, pieces)

    @dr.syntax
    def sample(self, mode: dr.ADMode, scene: mi.Scene, sampler: mi.Sampler, ray: mi.Ray3f,
               δL: mi.Spectrum | None, state_in: mi.Spectrum | None, active: mi.Bool,
               **kwargs) -> tuple[mi.Spectrum, mi.Bool, list[mi.Float], mi.Spectrum]:
        primal = mode == dr.ADMode.Primal
        geometry = self.geometry(scene)
        lathes = geometry.lathes
        check = self.normal_check
        bsdf_ctx = mi.BSDFContext()

        ray = mi.Ray3f(dr.detach(ray))            # Current ray
        depth = mi.UInt32(0)                      # Number of surface interactions so far
        L = mi.Spectrum(0 if primal else state_in)  # Radiance (primal), then what is left of it
        δL = mi.Spectrum(δL if δL is not None else 0)  # Adjoint / tangent radiance
        β = mi.Spectrum(1)                        # Path throughput weight
        η = mi.Float(1)                           # Product of relative IORs (Russian roulette)
        active = mi.Bool(active)                  # Lanes whose path is still going
        if dr.hint(self.hide_emitters, mode="scalar"):
            ray = geometry.skip_area_emitters(ray, active)  # as Mitsuba's prb
        si = geometry.ray_intersect(ray, active, True)  # Current (detached) interaction
        ray_prev = mi.Ray3f(ray)                  # Ray that found the previous vertex ...
        si_prev = dr.zeros(mi.SurfaceInteraction3f)  # ... and that vertex (detached)
        bsdf_pdf_prev = mi.Float(1.0)             # BSDF pdf of the direction that led here
        bsdf_delta_prev = mi.Bool(True)           # ... and whether it was a Dirac delta
        # Alpha: the camera ray met a surface, or a visible environment
        valid_ray = mi.Bool(not self.hide_emitters and scene.environment() is not None)

        while dr.hint(active, max_iterations=self.max_depth, label=f"lathe_prb ({mode.name})"):
            valid_ray |= active & si.is_valid() & (depth == 0)
            si_detached = si
            with dr.resume_grad(when=not primal):
                if dr.hint(not primal, mode="scalar"):
                    si = attach_lathe_hits(lathes, ray, si)
                    si.wi = _moving_wi(lathes, ray_prev, si_prev, si, active & (depth >= 1))

            # -------- Eq. 11, incident side (eq. 25: decided detached) --------
            active_next = active & si.is_valid() & (depth + 1 < self.max_depth)
            cos_in_geo = dr.detach(dr.dot(si.n, -ray.d))
            bad_in = active_next & (cos_in_geo * dr.detach(mi.Frame3f.cos_theta(si.wi)) <= 0.0)
            if dr.hint(check == "terminate", mode="scalar"):
                active_next &= ~bad_in
            elif dr.hint(check == "fallback", mode="scalar"):
                with dr.resume_grad(when=not primal):
                    si = with_geometric_frame(si, bad_in)

            bsdf = si.bsdf(ray)

            # ---------------- Direct emission (BSDF-sampled) ----------------
            ds = mi.DirectionSample3f(scene, si=si_detached, ref=si_prev)
            mis = mis_weight(bsdf_pdf_prev, scene.pdf_emitter_direction(si_prev, ds, ~bsdf_delta_prev))
            show = active & (depth > 0) if self.hide_emitters else active
            with dr.resume_grad(when=not primal):
                Le = β * mis * ds.emitter.eval(si, show)

            # ---------------------- Emitter sampling ----------------------
            active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            ds, em_weight = scene.sample_emitter_direction(si_detached, sampler.next_2d(), False, active_em)
            active_em &= ds.pdf != 0.0
            wi_sh = dr.detach(mi.Frame3f.cos_theta(si.wi))
            if dr.hint(check != "none", mode="scalar"):
                side_geo = dr.dot(si_detached.n, ds.d) * cos_in_geo
                side_sh = mi.Frame3f.cos_theta(dr.detach(si.to_local(ds.d))) * wi_sh
                active_em &= side_geo * side_sh > 0.0
            active_em &= ~geometry.ray_test(si_detached.spawn_ray_to(ds.p), active_em)
            with dr.resume_grad(when=not primal):
                if dr.hint(not primal, mode="scalar"):
                    ds, em_weight = _reattach_emitter_sample(scene, si, ds, em_weight, active_em)
                bsdf_val_em, bsdf_pdf_em = bsdf.eval_pdf(bsdf_ctx, si, si.to_local(ds.d), active_em)
                mis_em = dr.select(ds.delta, 1, mis_weight(ds.pdf, bsdf_pdf_em))
                Lr_dir = dr.select(active_em, β * mis_em * bsdf_val_em * em_weight, 0)

            # ------------------ Detached BSDF sampling -------------------
            si_used = dr.detach(si)  # the frame the direction is drawn in
            bs, bsdf_weight = bsdf.sample(bsdf_ctx, si_used, sampler.next_1d(), sampler.next_2d(),
                                          active_next)
            wo_world = si_used.to_world(bs.wo)
            if dr.hint(check != "none", mode="scalar"):
                bad_out = active_next & contradicts(si_detached, cos_in_geo, bs, wo_world)  # eq. 11, detached
                if dr.hint(check == "fallback", mode="scalar"):
                    bs, bsdf_weight, wo_world = _resample_geometric(bsdf, bsdf_ctx, sampler, si_used, bad_out,
                                                                    (bs, bsdf_weight, wo_world))
                    with dr.resume_grad(when=not primal):
                        si = with_geometric_frame(si, bad_out)
                else:
                    active_next &= ~bad_out

            L = (L + Le + Lr_dir) if primal else (L - Le - Lr_dir)
            ray_next = si_detached.spawn_ray(wo_world)
            η *= bs.eta
            β *= bsdf_weight
            bsdf_pdf_prev = bs.pdf
            bsdf_delta_prev = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)

            # ---------------------- Russian roulette ----------------------
            β_max = dr.max(mi.unpolarized_spectrum(β))
            active_next &= β_max != 0
            rr_prob = dr.minimum(β_max * dr.square(η), 0.95)
            rr_active = depth >= self.rr_depth
            β[rr_active] *= dr.rcp(rr_prob)
            active_next &= ~rr_active | (sampler.next_1d() < rr_prob)

            si_next = geometry.ray_intersect(ray_next, active_next)

            # ------------------ Differential phase only ------------------
            if dr.hint(not primal, mode="scalar"):
                with dr.resume_grad():
                    # The reflected radiance L, re-weighted by the attached
                    # BSDF value and solid-angle change of this vertex
                    J = solid_angle_to_area_jacobian(si.p, si_next.p, si_next.n,
                                                     active_next & si_next.is_valid())
                    wo_diff = dr.select(si_next.is_valid(), dr.normalize(si_next.p - si.p), ray_next.d)
                    wo = si.to_local(dr.replace_grad(ray_next.d, wo_diff))
                    bsdf_val = bsdf.eval(bsdf_ctx, si, wo, active_next)
                    Lr_ind = L * dr.relative_grad(bsdf_val) * dr.relative_grad(J)
                    Lo = Le + Lr_dir + Lr_ind
                    # An invisible lathe leaves Lo detached: zero derivative
                    if dr.hint(dr.grad_enabled(Lo), mode="scalar"):
                        if dr.hint(mode == dr.ADMode.Backward, mode="scalar"):
                            dr.backward_from(δL * Lo)
                        else:
                            δL += dr.forward_to(Lo)

            depth[si_detached.is_valid()] += 1
            active = active_next
            ray_prev = ray
            si_prev = si_detached
            ray = ray_next
            si = si_next

        return (L if primal else δL, valid_ray, [], L)

    def to_string(self) -> str:
        depth = -1 if self.max_depth == 0xFFFFFFFF else self.max_depth
        return (f"LathePRBIntegrator[max_depth={depth}, rr_depth={self.rr_depth}, "
                f"hide_emitters={self.hide_emitters}, normal_check='{self.normal_check}']")


def register() -> None:
    """Register ``<integrator type="lathe_prb">`` for the active variant."""
    register_jit_plugin(mi.register_integrator, "lathe_prb", LathePRBIntegrator, lambda props: "lathe_prb")
