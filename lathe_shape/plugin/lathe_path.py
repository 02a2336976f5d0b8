"""The ``lathe_path`` integrator: path tracing with exact lathes (parameters:
:class:`LathePathIntegrator`).

Every ``lathe`` in the scene is intersected exactly by its kernel, merged with
Mitsuba's hit on the rest of the scene (see :mod:`lathe_shape.plugin.scene_geometry`);
a ray that passes straight through a lathe's surface goes on along the same
line from the crossing it took, without an offset, so no crossing is skipped
or taken twice (:mod:`lathe_shape.plugin.line_walk`);
all other shapes, BSDFs and emitters are Mitsuba's own. The estimator follows
Mitsuba's ``path``: emitter sampling and BSDF sampling combined with multiple
importance sampling (power heuristic), Russian roulette after ``rr_depth``.
Participating media are not handled.

Why ``fallback`` is the default: in a white furnace (a glass under a uniform
white sky, where every pixel must be 1; ``scripts/furnace.py``, figures in
docs/benchmarks.md) ``terminate`` loses energy along the profile's joints, ``none``
leaves speckles exactly as stock ``path`` does on the smooth-shaded mesh, and
``fallback`` keeps the energy with the fewest speckles. With ``smooth`` false
nothing can contradict and the policies agree. Under ``terminate`` and
``fallback`` emitter-sampled directions are checked too (rejected where they
contradict the real surface). ``fallback`` is a heuristic: for non-delta
BSDFs a redrawn direction enters MIS with its geometric-frame pdf, a small
bias at the rare contradicting vertices.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .caustic_path_state import caustic_emitter_factor, caustic_vertex, start_caustic_path
from .caustic_paths import CausticTracer
from .caustic_render import CausticSettings, caustic_setup, render_with_caustics
from .integrator_base import (
    NORMAL_CHECKS,
    ExactLatheSamplingIntegrator,
    contradicts,
    mis_weight,
    normal_check_parameter,
    sample_with_fallback,
    with_geometric_frame,
)
from .line_walk import start_walk
from .params import path_parameters, typed_property
from .variants import register_jit_plugin

# (NORMAL_CHECKS, contradicts, mis_weight, sample_with_fallback and
# with_geometric_frame live in integrator_base; importable from here too)
__all__ = ["AOV_CHANNELS", "LathePathIntegrator", "NORMAL_CHECKS", "contradicts", "mis_weight", "parse_aovs",
           "register", "sample_with_fallback", "with_geometric_frame"]

#: The guide images of the ``aovs`` parameter and their channel names.
AOV_CHANNELS = {"albedo": ("albedo.R", "albedo.G", "albedo.B"), "nn": ("nn.X", "nn.Y", "nn.Z")}


def parse_aovs(text: str, who: str = "lathe_path") -> tuple[str, ...]:
    """The ``aovs`` parameter (``"albedo,nn"``) -> ``("albedo", "nn")``."""
    names = tuple(name.strip() for name in text.split(",") if name.strip())
    for name in names:
        if name not in AOV_CHANNELS:
            raise ValueError(
                f"{who}: parameter 'aovs': unknown guide '{name}' (expected: {', '.join(AOV_CHANNELS)})"
            )
    if len(set(names)) != len(names):
        raise ValueError(f"{who}: parameter 'aovs' names a guide twice: '{text}'")
    return names


def guide_parameters(props: mi.Properties, who: str) -> tuple[tuple[str, ...], bool]:
    """The ``aovs`` (parsed, see :func:`parse_aovs`; RGB variants only) and
    ``aov_through_delta`` parameters of a path tracer, errors naming
    ``who``."""
    aovs = parse_aovs(typed_property(props, "aovs", str, "", who), who)
    if aovs and not mi.is_rgb:
        raise ValueError(f"{who}: parameter 'aovs' needs an RGB variant (the guides are RGB images); "
                         f"this is '{mi.variant()}'")
    return aovs, typed_property(props, "aov_through_delta", bool, True, who)


def surface_guides(bsdf: mi.BSDFPtr, si: mi.SurfaceInteraction3f, beta: mi.Spectrum, smooth: mi.Bool,
                   active: mi.Bool) -> tuple[mi.Spectrum, mi.Vector3f]:
    """The guides at a surface vertex: the albedo (the diffuse reflectance
    where the BSDF is smooth, else 1, times the path throughput ``beta``,
    clipped to [0, 1]) and the shading normal turned to face the ray."""
    reflectance = dr.select(smooth, bsdf.eval_diffuse_reflectance(si, active), 1.0)
    facing = dr.select(mi.Frame3f.cos_theta(si.wi) < 0.0, -si.sh_frame.n, si.sh_frame.n)
    return dr.clip(beta * reflectance, 0.0, 1.0), facing


def guide_channels(aovs: tuple[str, ...], albedo: mi.Spectrum, normal: mi.Vector3f) -> list[mi.Float]:
    """The AOV channels of the guides ``aovs`` (none without guides: the
    albedo is then not read, so it may be any spectrum)."""
    guides = {"albedo": lambda: [albedo.x, albedo.y, albedo.z], "nn": lambda: [normal.x, normal.y, normal.z]}
    return [channel for name in aovs for channel in guides[name]()]


class LathePathIntegrator(ExactLatheSamplingIntegrator):
    """Path tracer that renders every ``lathe`` shape exactly.

    .. pluginparameters::

     * - max_depth
       - |int|
       - Longest path depth (-1 = infinite). 1 renders only directly visible
         emitters, 2 direct illumination, and so on. (Default: -1)

     * - rr_depth
       - |int|
       - Path depth from which Russian roulette may stop paths. (Default: 5)

     * - hide_emitters
       - |bool|
       - Hide directly visible emitters, as Mitsuba's ``path`` does: a camera
         ray goes on through the area emitters it meets first, and the
         environment seen directly (or only through ``null`` surfaces) is
         black with alpha 0. (Default: false)

     * - normal_check
       - |string|
       - What to do where the interpolated shading normal contradicts the real
         surface (the paper's eq. 11): ``none`` traces on as stock Mitsuba does;
         ``terminate`` stops the path there (the paper's rule); ``fallback``
         redoes that vertex with the geometric normal, which conserves
         energy for dielectrics and removes the speckles of ``none``.
         (Default: ``fallback``)

     * - aovs
       - |string|
       - Comma-separated guide images for a denoiser, appended after the
         image's RGB(A) channels in this order: ``albedo`` (channels
         ``albedo.R``, ``albedo.G``, ``albedo.B``) and ``nn`` (the shading
         normal, ``nn.X``, ``nn.Y``, ``nn.Z``, world space, turned to face the
         ray), named as Mitsuba's ``aov`` integrator names them. (Default: none)

     * - caustics
       - |bool|
       - Also trace caustic paths from the lights: particles sent from area,
         point, spot and directional lights and the environment towards the
         lathes, through glass (Dirac delta
         surfaces) onto a diffuse surface seen by the camera, and connected
         to the camera there, straight or, where the camera sees the
         surface through glass, along the chain of refractions a Newton
         solver finds; combined with path tracing by multiple
         importance sampling, so the image stays unbiased and its caustics
         converge many times faster. Point and spot light caustics, which
         path tracing cannot find, appear only with it. Needs an RGB variant,
         a ``perspective`` sensor and a film that is not a special one
         (``hdrfilm``, not ``specfilm``); ignored (path tracing alone) with
         ``hide_emitters``. They cost 1.16-1.26x plain path tracing's
         time per sample at 256 spp (more at fewer spp): where the scene's
         visible caustic is small, false is faster. (Default: true)

     * - caustic_paths
       - |float|
       - Light particles per camera sample for ``caustics``: more make the
         caustics converge faster and cost more (a particle costs about
         three camera samples, as it always goes through glass). A render
         traces at most 2^32 - 2^24 particles (``caustic_paths`` x spp x
         film pixels): more is refused with an error. (Default: 0.03)

     * - caustic_camera_chains
       - |float|
       - Share (0 to 1) of the particles landing where the camera sees them
         only through glass that solve for the chain of refractions to the
         camera (a solve costs about 15 camera samples); 0 leaves caustics
         seen through glass to path tracing alone. (Default: 0.3)

     * - caustic_max_chain
       - |int|
       - Most specular vertices between the light and the diffuse surface,
         and between the diffuse surface and the camera, on a light-traced
         caustic path (the two together also bounded by ``max_depth`` - 2);
         longer chains are path traced alone. (Default: 8)

     * - aov_through_delta
       - |bool|
       - Where the guides are taken: ``true`` at the first vertex whose BSDF
         is not a Dirac delta, seen through glass and mirrors (the albedo
         weighted by the delta bounces' throughput); ``false`` at the first
         surface hit, a glass surface then having albedo 1. (Default: true)
    """

    plugin_name = "lathe_path"

    def __init__(self, props: mi.Properties) -> None:
        who = type(self).plugin_name
        # Read before Mitsuba's base class reads hide_emitters (whose type error names no plugin)
        depths = path_parameters(props, who)
        super().__init__(props)
        self.max_depth, self.rr_depth, self.hide_emitters = depths
        self.normal_check = normal_check_parameter(props, who)
        #: The guide images rendered as AOVs (see ``aovs``), and where.
        self.aovs, self.aov_through_delta = guide_parameters(props, who)
        #: The caustic parameters (caustic_render.py)
        self.caustic_settings = CausticSettings.read(props, who)
        #: While a render with caustics runs: (tracer, particles per camera
        #: sample as an opaque Float) for the traced sample().
        self._caustic_render = None

    def caustic_setup(self, scene: mi.Scene, sensor: mi.Sensor) -> tuple[CausticTracer | None, str]:
        """The caustic tracer of a render of ``scene`` through ``sensor``
        and ``""`` or, where caustics are off or unsupported, ``None`` and
        why."""
        return caustic_setup(self, self.caustic_settings, scene, sensor, self.normal_check, media=False)

    def render(self, scene: mi.Scene, sensor: int | mi.Sensor = 0, seed: int = 0, spp: int = 0,
               develop: bool = True, evaluate: bool = True) -> mi.TensorXf:
        """Mitsuba's render, plus the light-traced caustic paths
        (``caustics``; eq. 32), added to the developed image and to the
        film."""
        return render_with_caustics(self, self.caustic_settings, super().render, scene, sensor, seed, spp,
                                    develop, evaluate)

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
        check = self.normal_check
        bsdf_ctx = mi.BSDFContext()

        ray = mi.Ray3f(ray)                  # Current ray
        walk = start_walk(dr.width(ray.d))   # Its line and last lathe crossing (line_walk.py)
        depth = mi.UInt32(0)                 # Number of surface interactions so far
        L = mi.Spectrum(0.0)                 # Radiance accumulated along the path
        beta = mi.Spectrum(1.0)              # Path throughput weight
        eta = mi.Float(1.0)                  # Product of relative IORs (for Russian roulette)
        active = mi.Bool(active) & (self.max_depth > 0)  # Lanes whose path is still going
        si_prev = dr.zeros(mi.Interaction3f)  # Previous vertex (for MIS; no more than MIS needs)
        bsdf_pdf_prev = mi.Float(1.0)        # BSDF pdf of the direction that led here
        bsdf_delta_prev = mi.Bool(True)      # ... and whether it was a Dirac delta
        # Alpha: the path met a surface (not only null ones) or a visible environment
        valid_ray = mi.Bool(not self.hide_emitters and scene.environment() is not None)
        want_guides = len(self.aovs) > 0
        through_delta = self.aov_through_delta
        albedo = mi.Spectrum(0.0)            # Albedo guide (AOV)
        normal = mi.Vector3f(0.0)            # Normal guide (AOV)
        guide_open = mi.Bool(want_guides)    # Lanes whose guide vertex is still ahead
        # The emitter sample of the last vertex waits for the next query,
        # which tests its shadow ray in the same traced lathe traversal
        # (ExactSceneGeometry.walk_and_test: compiled once, not twice).
        # (Arrays of the rays' width: the lathe kernels' per-lane stacks
        # misbehave on a ray made of scalars.)
        shadow = dr.zeros(mi.Ray3f, dr.width(ray.d))     # Its shadow ray
        em_pending = dr.zeros(mi.Bool, dr.width(ray.d))  # Lanes with one to test
        em_value = mi.Spectrum(0.0)                      # Its contribution if unoccluded
        # Eq. 32: caustic paths, also traced from the lights (see render)
        caustics = self._caustic_render
        tracer, per_camera_sample, deferred = caustics if caustics is not None else (None, None, None)
        caustic_path = start_caustic_path(ray.d)  # Eqs. 32, 40: is the path a caustic path?
                                                  # (caustic_path_state.py)

        if dr.hint(self.hide_emitters, mode="scalar"):
            ray = geometry.skip_area_emitters(ray, active)  # as Mitsuba's path

        # (a lane whose path ended runs once more to test a pending shadow ray)
        while dr.hint(active | em_pending, max_iterations=-1, label="lathe_path"):
            # (coherent camera rays: Embree traces them faster, as in Mitsuba's path)
            si, walk, occluded = geometry.walk_and_test(ray, active, walk, depth == 0, shadow, em_pending)
            L += dr.select(em_pending & ~occluded, em_value, 0.0)
            valid = si.is_valid()

            # ---------------- Direct emission (BSDF-sampled) ----------------
            ds = mi.DirectionSample3f(scene, si=si, ref=si_prev)
            em_pdf = scene.pdf_emitter_direction(si_prev, ds, ~bsdf_delta_prev)
            mis_bsdf = dr.select(bsdf_delta_prev, 1.0, mis_weight(bsdf_pdf_prev, em_pdf))
            emitted = ds.emitter.eval(si, active)
            if dr.hint(caustics is not None, mode="scalar"):
                # Eq. 32: a caustic path that the light tracer samples too,
                # ending on an area light or the environment (eq. 35); eq. 40
                # through a camera chain
                mis_bsdf *= caustic_emitter_factor(tracer, deferred, per_camera_sample, caustic_path, active,
                                                   ~valid, ds, si, ray, si_prev, si_prev.p,
                                                   beta * mis_bsdf * emitted)
            L += dr.select(active, beta * mis_bsdf * emitted, 0.0)

            active_next = active & valid & (depth + 1 < self.max_depth)

            # -------- Eq. 11, incident side: I . N* must agree with I . N --------
            wi_world = -ray.d
            cos_in_geo = dr.dot(si.n, wi_world)
            bad_in = active_next & (cos_in_geo * mi.Frame3f.cos_theta(si.wi) <= 0.0)
            if dr.hint(check == "terminate", mode="scalar"):
                active_next &= ~bad_in
            elif dr.hint(check == "fallback", mode="scalar"):
                # (the geometric frame is made once, for both redraws of
                # this vertex: its code is in the render kernel once)
                geo_frame = mi.Frame3f(si.n)
                si = with_geometric_frame(si, bad_in, geo_frame)

            bsdf = si.bsdf(ray)

            # ------------- Denoiser guides (the aovs parameter) -------------
            if dr.hint(want_guides, mode="scalar"):
                smooth = mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
                here = guide_open & active & valid & (smooth if through_delta else True)
                albedo[here], normal[here] = surface_guides(bsdf, si, beta, smooth, here)
                # A miss (or a path ended by max_depth) shows the emitter seen.
                gone = guide_open & active & (~valid | ~active_next)
                albedo[gone & ~here] = dr.clip(beta * emitted, 0.0, 1.0)
                guide_open &= ~(here | gone)

            # ---------------------- Emitter sampling ----------------------
            active_em = active_next & mi.has_flag(bsdf.flags(), mi.BSDFFlags.Smooth)
            ds, em_weight = scene.sample_emitter_direction(si, sampler.next_2d(), False, active_em)
            active_em &= ds.pdf != 0.0
            if dr.hint(check != "none", mode="scalar"):
                # Eq. 11 for the light direction: its side of the real
                # surface must agree with its side of the shading frame.
                side_geo = dr.dot(si.n, ds.d) * cos_in_geo
                side_sh = mi.Frame3f.cos_theta(si.to_local(ds.d)) * mi.Frame3f.cos_theta(si.wi)
                active_em &= side_geo * side_sh > 0.0
            shadow = si.spawn_ray_to(ds.p)
            em_pending = active_em

            # --- One BSDF call: the light direction's value and pdf, and
            # the sampled direction (as Mitsuba's path: one dispatch) ---
            wo_em = si.to_local(ds.d)
            sample_1, sample_2 = sampler.next_1d(), sampler.next_2d()
            # (on every surface hit, as path: a path ending on a null
            # surface must still see its sampled type, for the alpha)
            if dr.hint(check == "fallback", mode="scalar"):
                # Eq. 11, outgoing side, where the sample contradicts the
                # real surface: redone with the geometric normal, through
                # the same BSDF call (compiled once)
                redraws = (sampler.next_1d(), sampler.next_2d())
                bsdf_val_em, bsdf_pdf_em, bs, bsdf_weight, wo_world, redrawn = sample_with_fallback(
                    bsdf, bsdf_ctx, si, wo_em, (sample_1, sample_2), redraws, cos_in_geo, active_next,
                    active & valid, geo_frame)
            else:
                bsdf_val_em, bsdf_pdf_em, bs, bsdf_weight = bsdf.eval_pdf_sample(
                    bsdf_ctx, si, wo_em, sample_1, sample_2, active & valid)
                wo_world = si.to_world(bs.wo)
                redrawn = mi.Bool(False)
                if dr.hint(check == "terminate", mode="scalar"):
                    # Eq. 11, outgoing side: such a path ends here
                    active_next &= ~contradicts(si, cos_in_geo, bs, wo_world)
            mis_em = dr.select(ds.delta, 1.0, mis_weight(ds.pdf, bsdf_pdf_em))
            em_value = beta * mis_em * bsdf_val_em * em_weight

            if dr.hint(caustics is not None, mode="scalar"):
                # Eqs. 32 and 40: is this vertex D, or one of the chains?
                # (bad_in, redrawn: the fallback policy changed the frame)
                caustic_path = caustic_vertex(tracer, caustic_path, mi.Bool(True),
                                              active_next & (bs.pdf > 0.0), depth, si, bsdf, bs, wo_world,
                                              cos_in_geo, bad_in, ~redrawn)

            # ------------------ Update the loop state ------------------
            valid_ray |= active & valid & ~mi.has_flag(bs.sampled_type, mi.BSDFFlags.Null)
            ray = si.spawn_ray(wo_world)
            beta *= bsdf_weight
            eta *= bs.eta
            si_prev = mi.Interaction3f(si)
            bsdf_pdf_prev = bs.pdf
            bsdf_delta_prev = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta)
            depth += 1

            # ---------------------- Russian roulette ----------------------
            beta_max = dr.max(beta)
            active_next &= beta_max != 0.0
            rr_prob = dr.minimum(beta_max * dr.square(eta), 0.95)
            rr_active = depth >= self.rr_depth
            beta[rr_active] *= dr.rcp(rr_prob)
            active_next &= ~rr_active | (sampler.next_1d() < rr_prob)
            active = active_next

        # A hidden environment seen directly, or only through null surfaces, is black
        return dr.select(valid_ray, L, 0.0), valid_ray, guide_channels(self.aovs, albedo, normal)

    def aov_names(self) -> list[str]:
        return [channel for name in self.aovs for channel in AOV_CHANNELS[name]]

    def to_string(self) -> str:
        depth = -1 if self.max_depth == 0xFFFFFFFF else self.max_depth
        settings = self.caustic_settings
        return (
            f"LathePathIntegrator[max_depth={depth}, rr_depth={self.rr_depth}, "
            f"hide_emitters={self.hide_emitters}, normal_check='{self.normal_check}', "
            f"aovs='{','.join(self.aovs)}', caustics={settings.enabled}, caustic_paths={settings.paths}, "
            f"caustic_max_chain={settings.max_chain}]"
        )


def register() -> None:
    """Register ``<integrator type="lathe_path">`` for the active variant."""
    register_jit_plugin(mi.register_integrator, "lathe_path", LathePathIntegrator, lambda props: "lathe_path",
                        polarized=False)
