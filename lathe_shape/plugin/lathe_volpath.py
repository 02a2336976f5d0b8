"""The ``lathe_volpath`` integrator: volumetric path tracing with exact lathes
(parameters: :class:`LatheVolpathIntegrator`).

What it renders: Mitsuba's ``volpath`` semantics over scenes whose ``lathe``
shapes are intersected exactly (every ray query goes through
:class:`~lathe_shape.plugin.scene_geometry.ExactSceneGeometry`, so a path
length inside a lathe is measured between its exact surfaces). Each lane
carries the Mitsuba medium it travels in (``mi.MediumPtr``; the camera's
medium at the start). The ``interior``/``exterior`` media of every shape,
lathes included (a lathe is an ``mi.Mesh``, so Mitsuba's own
``si.target_medium`` serves), are entered and left at the surfaces whose
``interior``/``exterior`` differ.

* Free flights are sampled with the medium's majorant
  (``Medium.sample_interaction``) up to the next exact surface hit, in a
  colour channel drawn at random for each flight; the weight divides by
  the *mean* of the channels' free-flight pdfs (one-sample MIS over the
  channels, balance heuristic), less noisy in strongly coloured media (a
  green bottle) than Mitsuba's single channel chosen once per path. (The
  channel must be drawn anew per flight: kept for the whole path, the
  per-flight MIS weights multiply into a biased estimate, measured as a
  0.8% too bright green bottle.) Homogeneous media absorb and scatter (real collisions with
  probability 1: no null collisions); heterogeneous media (``grid``
  volumes) use delta tracking: a collision is real with probability
  ``mean(sigma_t / majorant)``, else null (the path goes on straight,
  its surface hit kept).
* At a real collision the medium's phase function is sampled, with emitter
  sampling where the medium asks for it (``use_emitter_sampling``).
* At a surface: emission (MIS with the previous scattering vertex's
  pdf), emitter sampling, BSDF sampling; where the surface is a medium
  transition the lane's medium becomes ``si.target_medium(d)``. A straight
  continuation (a ``null`` interface, an index-matched dielectric) goes on
  along the same line from the exact crossing
  (:mod:`~lathe_shape.plugin.line_walk`), so no lathe crossing is skipped or
  taken twice. ``null`` crossings are not vertices: the previous vertex and
  its pdf are kept for MIS, as in Mitsuba's ``volpath``.
* Shadow rays (emitter sampling) walk towards the emitter, as Mitsuba's
  ``volpath``'s: a surface whose BSDF has no ``Null`` lobe blocks them
  (dielectrics included); one that has (``null``, ``thindielectric``,
  ``mask``) is crossed, weighted by the BSDF's
  ``eval_null_transmission`` (a ``thindielectric`` sheet's transmittance
  ``1 - 2R / (1 + R)``, 1 for ``null``), changing the medium. In a
  homogeneous medium the transmittance of a segment is
  ``exp(-sigma_t * length)`` with the segment's length between exact hits;
  in a heterogeneous one it is estimated by ratio tracking.

* Caustics (``caustics``, as ``lathe_path``'s; eqs. 32-40 and 44 of
  docs/method.md): particles from the lights through the Dirac-delta
  lathes onto a diffuse surface, joined to the camera, carry the
  transmittance ``exp(-sigma_t * length)`` of every homogeneous medium they
  cross: the light that crosses the media without scattering, which is
  what path tracing samples with them (a path that scatters in a medium is
  path traced alone). Traced where every medium is homogeneous and the
  camera and the lights are outside every medium; elsewhere path tracing
  alone renders the caustics. As the shadow rays cross ``Null`` lobes, a
  path from ``D`` to the light through null crossings alone (a point light
  under a ``null`` or ``thindielectric`` sheet) is emitter sampling's, not
  a caustic path (eq. 32; :func:`~lathe_shape.plugin.caustic_paths.blocks_shadow_rays`):
  traced by both, it was counted twice (the floor under such a sheet
  1.96-2.03x too bright).

Not handled: polarization; the ``normal_check`` policies of ``lathe_path``
(the shading normals are used as stock Mitsuba uses them).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..kernels.top_level import NO_LATHE
from .caustic_path_state import caustic_emitter_factor, caustic_vertex, start_caustic_path
from .caustic_paths import CausticTracer
from .caustic_render import CausticSettings, caustic_setup, render_with_caustics
from .integrator_base import ExactLatheSamplingIntegrator, mis_weight
from .lathe_path import AOV_CHANNELS, guide_channels, guide_parameters, surface_guides
from .line_walk import LineWalk, start_walk
from .media_check import refuse_negative_extinction
from .media_segments import heterogeneous_medium
from .params import path_parameters
from .scene_geometry import ExactSceneGeometry
from .variants import register_jit_plugin

__all__ = ["LatheVolpathIntegrator", "register"]


def _select_walk(where: mi.Bool, a: LineWalk, b: LineWalk) -> LineWalk:
    """``a`` on the lanes ``where``, else ``b``."""
    fields = ("o", "d", "lathe", "s", "key", "t")
    return LineWalk(*(dr.select(where, getattr(a, f), getattr(b, f)) for f in fields))


def _reset_walk(walk: LineWalk, where: mi.Bool) -> LineWalk:
    """``walk`` forgotten on the lanes ``where`` (a new line starts there:
    after a medium scattering event)."""
    return LineWalk(walk.o, walk.d, dr.select(where, NO_LATHE, walk.lathe), walk.s, walk.key, walk.t)


class LatheVolpathIntegrator(ExactLatheSamplingIntegrator):
    """Volumetric path tracer that renders every ``lathe`` shape exactly.

    .. pluginparameters::

     * - max_depth
       - |int|
       - Longest path depth (-1 = infinite), counting surface and medium
         scattering events as Mitsuba's ``volpath`` does (crossings of
         ``null`` surfaces do not count). 1 renders only directly visible
         emitters, 2 direct illumination, and so on. (Default: -1)

     * - rr_depth
       - |int|
       - Path depth from which Russian roulette may stop paths. (Default: 5)

     * - hide_emitters
       - |bool|
       - Hide directly visible emitters, as Mitsuba's ``volpath`` does: a
         camera ray goes on through the area emitters it meets first, and the
         environment seen directly (or only through ``null`` surfaces) is
         black with alpha 0. (Default: false)

     * - caustics
       - |bool|
       - Also trace caustic paths from the lights, as ``lathe_path`` does
         (see there), each particle weighted by the transmittance of the
         homogeneous media it crosses (coloured glass, a liquid); combined
         with path tracing by multiple importance sampling, so the image
         stays unbiased. Traced where every medium is homogeneous and the
         sensor and the lights have no medium; needs an RGB variant, a
         ``perspective`` sensor and an RGB film; ignored (path tracing
         alone) with ``hide_emitters`` or where these do not hold.
         (Default: true)

     * - caustic_paths
       - |float|
       - Light particles per camera sample for ``caustics`` (at most
         2^32 - 2^24 particles per render, as for ``lathe_path``).
         (Default: 0.03)

     * - caustic_camera_chains
       - |float|
       - Share (0 to 1) of the particles landing where the camera sees them
         only through glass that solve for the chain of refractions to the
         camera; 0 leaves caustics seen through glass to path tracing
         alone. (Default: 0.3)

     * - caustic_max_chain
       - |int|
       - Most specular vertices (``null`` crossings included) between the
         light and the diffuse surface, and between the diffuse surface and
         the camera, on a light-traced caustic path (the two together also
         bounded by ``max_depth`` - 2). (Default: 8)

     * - aovs
       - |string|
       - Comma-separated guide images for a denoiser, appended after the
         image's channels, as for ``lathe_path``: ``albedo`` and ``nn``,
         taken on the exact lathes. Where a path scatters in a medium before
         its guide vertex, the guides are taken there: the albedo is the
         path's throughput so far, the normal faces the camera ray.
         (Default: none)

     * - aov_through_delta
       - |bool|
       - As for ``lathe_path``: the guides at the first vertex whose BSDF is
         not a Dirac delta (``true``), or at the first surface hit.
         (Default: true)
    """

    plugin_name = "lathe_volpath"
    #: Media are what this integrator is for.
    refuses_media = False

    def __init__(self, props: mi.Properties) -> None:
        # Read before Mitsuba's base class reads hide_emitters (whose type error names no plugin)
        depths = path_parameters(props, type(self).plugin_name)
        super().__init__(props)
        self.max_depth, self.rr_depth, self.hide_emitters = depths
        who = self.plugin_name
        #: The guide images rendered as AOVs (see ``aovs``), and where.
        self.aovs, self.aov_through_delta = guide_parameters(props, who)
        #: The caustic parameters (caustic_render.py)
        self.caustic_settings = CausticSettings.read(props, who)
        #: While a render with caustics runs: (tracer, particles per camera
        #: sample as an opaque Float, eq. 40's deferred solves) for the traced sample().
        self._caustic_render = None

    def caustic_setup(self, scene: mi.Scene, sensor: mi.Sensor) -> tuple[CausticTracer | None, str]:
        """The caustic tracer of a render of ``scene`` through ``sensor``
        and ``""`` or, where caustics are off or unsupported, ``None`` and
        why. (The shading normals are used as stock Mitsuba does: the
        tracer's ``normal_check`` is ``none``.)"""
        return caustic_setup(self, self.caustic_settings, scene, sensor, "none", media=True)

    def render(self, scene: mi.Scene, sensor: int | mi.Sensor = 0, seed: int = 0, spp: int = 0,
               develop: bool = True, evaluate: bool = True) -> mi.TensorXf:
        """Mitsuba's render, plus the light-traced caustic paths
        (``caustics``; eq. 32), added to the developed image and to the
        film."""
        refuse_negative_extinction(scene, self.plugin_name)
        return render_with_caustics(self, self.caustic_settings, super().render, scene, sensor, seed, spp,
                                    develop, evaluate)

    @staticmethod
    def _heterogeneous(scene: mi.Scene) -> bool:
        """Whether any shape bounds a medium that is not homogeneous (null
        collisions must then be handled)."""
        return heterogeneous_medium(scene) is not None

    @dr.syntax
    def transmittance(self, geometry: ExactSceneGeometry, sampler: mi.Sampler, ref: mi.Interaction3f,
                      ds: mi.DirectionSample3f, medium: mi.MediumPtr, channel: mi.UInt32,
                      null_collisions: bool, active: mi.Bool) -> mi.Spectrum:
        """Transmittance from ``ref`` (in ``medium``) to the emitter sample
        ``ds``: 0 where a surface without a ``Null`` lobe is in between;
        through those with one (media changing there) the product of their
        ``eval_null_transmission`` (as Mitsuba's ``volpath``: a
        ``thindielectric`` sheet's ``1 - 2R / (1 + R)``) and of the
        segments' transmittances (closed form in homogeneous media, ratio
        tracking in others)."""
        ray = ref.spawn_ray_to(ds.p)
        remaining = mi.Float(ray.maxt)          # distance left to the emitter (units of ray.d)
        walk = start_walk(dr.width(ray.d))
        medium = mi.MediumPtr(medium)
        tr = mi.Spectrum(1.0)
        si = dr.zeros(mi.SurfaceInteraction3f, dr.width(ray.d))
        need_hit = mi.Bool(True)                 # the next surface is not known yet
        active = mi.Bool(active)
        while active:
            ray.maxt = remaining
            si_new, walk_new = geometry.ray_intersect_walk(ray, active & need_hit, walk)
            si[need_hit] = si_new
            walk = _select_walk(need_hit, walk_new, walk)
            need_hit = mi.Bool(False)
            seg = dr.minimum(si.t, remaining)    # length to the surface or to the emitter
            in_medium = active & (medium != None)  # noqa: E711 (Dr.Jit's test)
            homogeneous = medium.is_homogeneous()
            collided = mi.Bool(False)
            if dr.hint(null_collisions, mode="scalar"):
                # Ratio tracking through a heterogeneous medium
                ray_m = mi.Ray3f(ray)
                ray_m.maxt = seg
                tracked = in_medium & ~homogeneous
                mei = medium.sample_interaction(ray_m, sampler.next_1d(tracked), channel, tracked)
                collided = tracked & mei.is_valid()
                tr[collided] *= mei.sigma_n / mei.combined_extinction
                ray.o[collided] = mei.p
                remaining[collided] = remaining - mei.t
                si.t[collided] = si.t - mei.t
                in_medium &= homogeneous
            # Closed form through a homogeneous medium
            mei0 = dr.zeros(mi.MediumInteraction3f, dr.width(ray.d))
            mei0.p = ray.o
            mei0.wavelengths = ray.wavelengths
            mei0.medium = medium
            _, _, sigma_t = medium.get_scattering_coefficients(mei0, in_medium)
            tr[in_medium] *= dr.exp(-sigma_t * seg)
            passing = active & ~collided
            hit = passing & si.is_valid() & (si.t < remaining)
            bsdf = si.bsdf()
            null = mi.has_flag(bsdf.flags(), mi.BSDFFlags.Null)
            blocked = hit & ~null
            tr[blocked] = 0.0
            through = hit & null
            # The surface's own transmission (1 for null, the sheet's for
            # thindielectric, 1 - opacity for mask)
            tr[through] *= bsdf.eval_null_transmission(si, through)
            medium[through & si.is_medium_transition()] = si.target_medium(ray.d)
            ray_next = si.spawn_ray(ray.d)
            remaining[through] = remaining - si.t
            ray[through] = ray_next
            need_hit |= through
            active = (through | collided) & dr.any(tr != 0.0)
        return tr

    @dr.syntax
    def sample(
        self,
        scene: mi.Scene,
        sampler: mi.Sampler,
        ray: mi.RayDifferential3f,
        medium: mi.Medium = None,
        active: mi.Bool = True,
    ) -> tuple[mi.Spectrum, mi.Bool, list[mi.Float]]:
        geometry = self.geometry(scene)
        null_collisions = self._heterogeneous(scene)
        bsdf_ctx = mi.BSDFContext()
        phase_ctx = mi.PhaseFunctionContext(sampler)
        width = dr.width(ray.d)

        ray = mi.Ray3f(ray)                  # Current ray
        walk = start_walk(width)             # Its line and last lathe crossing (line_walk.py)
        medium = dr.zeros(mi.MediumPtr, width) if medium is None else mi.MediumPtr(medium)
        depth = mi.UInt32(0)                 # Scattering events so far (null crossings not counted)
        L = mi.Spectrum(0.0)                 # Radiance accumulated along the path
        beta = mi.Spectrum(1.0)              # Path throughput weight
        eta = mi.Float(1.0)                  # Product of relative IORs (for Russian roulette)
        active = mi.Bool(active) & (self.max_depth > 0)
        si = dr.zeros(mi.SurfaceInteraction3f, width)  # The ray's next surface hit
        need_hit = mi.Bool(True)             # ... not known yet (unknown after every turn)
        prev = dr.zeros(mi.Interaction3f, width)  # Previous scattering vertex (for MIS)
        pdf_prev = mi.Float(1.0)             # Its sampled direction's pdf
        delta_prev = mi.Bool(True)           # ... and whether it was a Dirac delta
        valid_ray = mi.Bool(not self.hide_emitters and scene.environment() is not None)
        n_channels = dr.size_v(mi.Spectrum)
        channel = mi.UInt32(0)               # Colour channel of the free flights (drawn per flight)
        crossings = mi.UInt32(0)             # Surface interactions so far (null crossings counted)
        # Eq. 32: caustic paths, also traced from the lights (see render)
        caustics = self._caustic_render
        tracer, per_camera_sample, deferred = caustics if caustics is not None else (None, None, None)
        caustic_path = start_caustic_path(ray.d)  # Eqs. 32, 40: is the path a caustic path?
                                                  # (caustic_path_state.py)
        want_guides = len(self.aovs) > 0
        through_delta = self.aov_through_delta
        albedo = mi.Spectrum(0.0)            # Albedo guide (AOV)
        normal = mi.Vector3f(0.0)            # Normal guide (AOV)
        guide_open = mi.Bool(want_guides)    # Lanes whose guide vertex is still ahead

        if dr.hint(self.hide_emitters, mode="scalar"):
            ray = geometry.skip_area_emitters(ray, active)

        while dr.hint(active, max_iterations=-1, label="lathe_volpath"):
            # ---------------- Next surface (exact lathes) ----------------
            si_new, walk_new = geometry.ray_intersect_walk(ray, active & need_hit, walk, depth == 0)
            si[need_hit] = si_new
            walk = _select_walk(need_hit, walk_new, walk)
            need_hit = mi.Bool(False)

            # ------------- Free flight through the current medium -------------
            in_medium = active & (medium != None)  # noqa: E711 (Dr.Jit's test)
            ray_m = mi.Ray3f(ray)
            ray_m.maxt = si.t
            # A colour channel drawn anew for every free flight: the weight
            # below (one-sample MIS over the channels) holds for one flight
            # only; a channel kept along the path would need the whole
            # path's pdfs in it (multiplied per flight it is biased).
            channel = mi.UInt32(dr.minimum(n_channels * sampler.next_1d(in_medium), n_channels - 1))
            mei = medium.sample_interaction(ray_m, sampler.next_1d(in_medium), channel, in_medium)
            mei.t[in_medium & (si.t < mei.t)] = dr.inf
            tr, ff_pdf = medium.transmittance_eval_pdf(mei, si, in_medium)
            pdf = dr.mean(ff_pdf)
            beta[in_medium] *= dr.select(pdf > 0.0, tr / pdf, 0.0)
            collided = in_medium & mei.is_valid()
            if dr.hint(null_collisions, mode="scalar"):
                scatter_prob = dr.mean(mei.sigma_t / mei.combined_extinction)
                null_event = collided & (sampler.next_1d(collided) >= scatter_prob)
                scatter = collided & ~null_event
                beta[null_event] *= mei.sigma_n / (1.0 - scatter_prob)
                # A null collision: straight on, the surface hit kept
                ray.o[null_event] = mei.p
                si.t[null_event] = si.t - mei.t
            else:
                scatter_prob = mi.Float(1.0)
                null_event = mi.Bool(False)
                scatter = mi.Bool(collided)
            beta[scatter] *= mei.sigma_s / scatter_prob
            depth[scatter] += 1
            scatter &= depth < self.max_depth
            on_surface = active & ~collided

            # ---------------- Emission of the surface reached ----------------
            ds = mi.DirectionSample3f(scene, si=si, ref=prev)
            emitted = ds.emitter.eval(si, on_surface)
            seen = on_surface & (ds.emitter != None)  # noqa: E711
            if dr.hint(self.hide_emitters, mode="scalar"):
                seen &= depth > 0
            em_pdf = scene.pdf_emitter_direction(prev, ds, seen & ~delta_prev)
            mis_bsdf = dr.select(delta_prev, 1.0, mis_weight(pdf_prev, em_pdf))
            if dr.hint(caustics is not None, mode="scalar"):
                # Eq. 32: a caustic path that the light tracer samples too
                # (no medium event on it), ending on an area light or the
                # environment (eq. 35); eq. 40 through a camera chain
                mis_bsdf *= caustic_emitter_factor(tracer, deferred, per_camera_sample, caustic_path, seen,
                                                   ~si.is_valid(), ds, si, ray, prev, ray.o,
                                                   beta * mis_bsdf * emitted)
            L[seen] += beta * mis_bsdf * emitted

            missed = on_surface & ~si.is_valid()
            on_surface &= si.is_valid()
            bsdf = si.bsdf(ray)

            # ------------- Denoiser guides (the aovs parameter) -------------
            if dr.hint(want_guides, mode="scalar"):
                smooth = mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
                here = guide_open & on_surface & (smooth if through_delta else True)
                albedo[here], normal[here] = surface_guides(bsdf, si, beta, smooth, here)
                # A scattering event in a medium first: the guides there
                in_volume = guide_open & scatter
                albedo[in_volume] = dr.clip(beta, 0.0, 1.0)
                normal[in_volume] = -ray.d
                # A miss shows the emitter seen
                gone = guide_open & missed
                albedo[gone] = dr.clip(beta * emitted, 0.0, 1.0)
                guide_open &= ~(here | in_volume | gone)

            # ---------------------- Emitter sampling ----------------------
            phase = mei.medium.phase_function()
            nee_medium = scatter & medium.use_emitter_sampling()
            nee_surface = (on_surface & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
                           & (depth + 1 < self.max_depth))
            nee = nee_medium | nee_surface
            ref = dr.select(nee_medium, mi.Interaction3f(mei), mi.Interaction3f(si))
            ds, em_weight = scene.sample_emitter_direction(ref, sampler.next_2d(nee), False, nee)
            nee &= ds.pdf != 0.0
            # The medium the shadow ray leaves in
            shadow_medium = mi.MediumPtr(medium)
            leaves = nee_surface & si.is_medium_transition()
            shadow_medium[leaves] = si.target_medium(ds.d)
            tr_em = self.transmittance(geometry, sampler, ref, ds, shadow_medium, channel,
                                       null_collisions, nee)
            bsdf_val, bsdf_pdf = bsdf.eval_pdf(bsdf_ctx, si, si.to_local(ds.d), nee_surface)
            phase_val, phase_pdf = phase.eval_pdf(phase_ctx, mei, ds.d, nee_medium)
            f_val = dr.select(nee_surface, bsdf_val, phase_val)
            f_pdf = dr.select(nee_surface, bsdf_pdf, phase_pdf)
            mis_em = dr.select(ds.delta, 1.0, mis_weight(ds.pdf, f_pdf))
            L[nee] += beta * f_val * em_weight * tr_em * mis_em

            # ---------------------- Phase sampling ----------------------
            wo_ph, phase_weight, phase_pdf = phase.sample(phase_ctx, mei, sampler.next_1d(scatter),
                                                          sampler.next_2d(scatter), scatter)
            scatter &= phase_pdf > 0.0
            beta[scatter] *= phase_weight
            ray[scatter] = mei.spawn_ray(wo_ph)
            prev[scatter] = mi.Interaction3f(mei)
            pdf_prev[scatter] = phase_pdf
            delta_prev[scatter] = False
            valid_ray |= scatter

            # ---------------------- BSDF sampling ----------------------
            bs, bsdf_weight = bsdf.sample(bsdf_ctx, si, sampler.next_1d(on_surface),
                                          sampler.next_2d(on_surface), on_surface)
            on_surface &= bs.pdf > 0.0
            if dr.hint(caustics is not None, mode="scalar"):
                # Eqs. 32 and 40: is this vertex D, or one of the chains? A
                # medium event ends both chains (lanes not on_surface).
                cos_in_geo = dr.dot(si.n, -ray.d)
                bad_in = cos_in_geo * mi.Frame3f.cos_theta(si.wi) <= 0.0
                caustic_path = caustic_vertex(tracer, caustic_path, on_surface, depth + 1 < self.max_depth,
                                              crossings, si, bsdf, bs, si.to_world(bs.wo), cos_in_geo, bad_in,
                                              mi.Bool(True))
                crossings += 1
            beta[on_surface] *= bsdf_weight
            eta[on_surface] *= bs.eta
            ray[on_surface] = si.spawn_ray(si.to_world(bs.wo))
            real = on_surface & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
            depth[real] += 1
            prev[real] = mi.Interaction3f(si)
            pdf_prev[real] = bs.pdf
            delta_prev[real] = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            valid_ray |= real
            medium[on_surface & si.is_medium_transition()] = si.target_medium(ray.d)

            # A new line after a medium scattering event; a new surface hit
            # after every event but a null collision
            walk = _reset_walk(walk, scatter)
            need_hit = scatter | on_surface
            active = scatter | null_event | (on_surface & (depth < self.max_depth))

            # ---------------------- Russian roulette ----------------------
            beta_max = dr.max(beta)
            active &= beta_max != 0.0
            rr_prob = dr.minimum(beta_max * dr.square(eta), 0.95)
            rr_active = active & (depth >= self.rr_depth)
            beta[rr_active] *= dr.rcp(rr_prob)
            active &= ~rr_active | (sampler.next_1d(rr_active) < rr_prob)

        return dr.select(valid_ray, L, 0.0), valid_ray, guide_channels(self.aovs, albedo, normal)

    def aov_names(self) -> list[str]:
        return [channel for name in self.aovs for channel in AOV_CHANNELS[name]]

    def to_string(self) -> str:
        depth = -1 if self.max_depth == 0xFFFFFFFF else self.max_depth
        return (f"LatheVolpathIntegrator[max_depth={depth}, rr_depth={self.rr_depth}, "
                f"hide_emitters={self.hide_emitters}, aovs='{','.join(self.aovs)}']")


def register() -> None:
    """Register ``<integrator type="lathe_volpath">`` for the active variant."""
    register_jit_plugin(mi.register_integrator, "lathe_volpath", LatheVolpathIntegrator,
                        lambda props: "lathe_volpath", polarized=False)
