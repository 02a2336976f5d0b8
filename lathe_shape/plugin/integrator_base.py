"""What the exact-lathe integrators share: their frame and eq. 11.

* :func:`exact_lathe_base`, the integrators' base class over Mitsuba's
  (:data:`ExactLatheSamplingIntegrator` over ``mi.SamplingIntegrator``):
  it keeps the scene's
  :class:`~lathe_shape.plugin.scene_geometry.ExactSceneGeometry` and builds
  it before Mitsuba's ``render`` queues its camera rays;
* :func:`normal_check_parameter`, the ``normal_check`` parameter of
  ``lathe_path``, ``lathe_whitted`` and ``lathe_prb``;
* the eq. 11 helpers (docs/method.md): :func:`contradicts`,
  :func:`with_geometric_frame` and :func:`sample_with_fallback`;
* :func:`mis_weight`, Mitsuba's power heuristic
  (``mitsuba.ad.integrators.common``).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
from mitsuba.ad.integrators.common import mis_weight

from .media_check import refuse_media
from .params import typed_property
from .scene_geometry import ExactSceneGeometry

__all__ = [
    "ExactLatheSamplingIntegrator",
    "NORMAL_CHECKS",
    "contradicts",
    "exact_lathe_base",
    "mis_weight",
    "normal_check_parameter",
    "sample_with_fallback",
    "with_geometric_frame",
]

#: Policies of the ``normal_check`` parameter (docs/method.md, eq. 11).
NORMAL_CHECKS = ("none", "terminate", "fallback")


def normal_check_parameter(props: mi.Properties, who: str) -> str:
    """The ``normal_check`` parameter (default ``fallback``), checked to be
    one of :data:`NORMAL_CHECKS`; errors name the plugin ``who``."""
    policy = typed_property(props, "normal_check", str, "fallback", who)
    if policy not in NORMAL_CHECKS:
        raise ValueError(
            f"{who}: parameter 'normal_check': unknown policy '{policy}' "
            f"(expected one of: {', '.join(NORMAL_CHECKS)})"
        )
    return policy


def exact_lathe_base(base: type) -> type:
    """The frame of an integrator that intersects every ``lathe`` exactly,
    as a subclass of Mitsuba's integrator class ``base``
    (``mi.SamplingIntegrator``, ``RBIntegrator``; nanobind classes take one
    base only, so this is no mixin). The integrators derive from it and set
    ``plugin_name`` (for error messages) and ``refuses_media``
    (participating media refused on lathes), and may override
    ``prepare_geometry``. Like every plugin class of the package it is bound
    to the variant active when it is made."""

    class ExactLatheIntegrator(base):
        #: The plugin's name, as the scene XML writes it.
        plugin_name = "lathe_path"
        #: Whether lathes with ``interior``/``exterior`` media are refused.
        refuses_media = True
        #: The scene's geometry while it has lathes (see :meth:`geometry`).
        _geometry: ExactSceneGeometry | None = None

        def geometry(self, scene: mi.Scene) -> ExactSceneGeometry:
            """The scene's exact-lathe ray queries; follows the scene's edits
            (see :meth:`ExactSceneGeometry.for_scene`)."""
            geometry = ExactSceneGeometry.for_scene(scene, self._geometry)
            if self.refuses_media:
                refuse_media(geometry.lathes, self.plugin_name)
            # Without lathes the geometry is the scene itself: not kept, as
            # the scene owns this integrator (a reference cycle).
            self._geometry = geometry if geometry.lathes else None
            self.prepare_geometry(geometry)
            return geometry

        def prepare_geometry(self, geometry: ExactSceneGeometry) -> None:
            """Whatever must be built from ``geometry`` outside traced loops
            (nothing here)."""

        def render(self, scene: mi.Scene, sensor: int | mi.Sensor = 0, seed: int = 0, spp: int = 0,
                   develop: bool = True, evaluate: bool = True) -> mi.TensorXf:
            """Mitsuba's render, with the scene geometry built first: built
            inside ``sample``, after the render has queued its camera rays,
            it would evaluate part of that work early and make the first
            render's kernel differ from every later one (a second
            compilation)."""
            self.geometry(scene)
            return super().render(scene, sensor, seed, spp, develop, evaluate)

    ExactLatheIntegrator.__name__ = ExactLatheIntegrator.__qualname__ = f"ExactLathe{base.__name__}"
    return ExactLatheIntegrator


#: The base of ``lathe_path``, ``lathe_whitted`` and ``lathe_volpath``.
ExactLatheSamplingIntegrator = exact_lathe_base(mi.SamplingIntegrator)


# ---------------------------------------------------------------------------
# Eq. 11: the interpolated shading normal against the real surface
# ---------------------------------------------------------------------------

def contradicts(si: mi.SurfaceInteraction3f, cos_in_geo: mi.Float, bs: mi.BSDFSample3f,
                wo_world: mi.Vector3f, weight: mi.Spectrum | None = None) -> mi.Bool:
    """Eq. 11, outgoing side: whether the sampled direction ``wo_world``
    contradicts the real surface (a reflection must stay on the incident
    side of the geometric normal, a transmission must cross it);
    ``cos_in_geo`` is the incident direction's cosine with ``si.n``.

    With the sample's ``weight``: a sample of weight zero contradicts
    nothing. (A one-sided lobe hit from behind, such as a ``mask``'s diffuse
    layer, returns a direction with a pdf but weight zero: the path is
    absorbed there. Counted as a contradiction, the ``fallback`` policy drew
    again and gave the path a second chance at the other lobe, adding
    energy: a masked diffuse cylinder in a white furnace read 0.90 where
    ``path`` reads 0.75.)"""
    reflected = mi.has_flag(bs.sampled_type, mi.BSDFFlags.Reflection)
    side = cos_in_geo * dr.dot(si.n, wo_world)
    found = (bs.pdf > 0.0) & dr.select(reflected, side <= 0.0, side >= 0.0)
    if weight is not None:
        found &= dr.any(mi.unpolarized_spectrum(dr.detach(weight)) != 0.0)
    return found


@dr.syntax
def sample_with_fallback(bsdf: mi.BSDFPtr, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f,
                         wo_em: mi.Vector3f, samples: tuple, redraws: tuple, cos_in_geo: mi.Float,
                         checked: mi.Bool, active: mi.Bool, geo_frame: mi.Frame3f) -> tuple:
    """The ``fallback`` policy's BSDF sampling: one ``eval_pdf_sample``
    call (the light direction ``wo_em``'s value and pdf, and a sampled
    direction), redone with the geometric frame and the ``redraws`` where
    the ``checked`` lanes' sample contradicts the real surface (eq. 11).
    Both passes go through the same call site in a loop, so the BSDFs'
    code is compiled once; packets without a contradicting vertex run it
    once. ``geo_frame``: ``mi.Frame3f(si.n)``, made once by the caller for
    this vertex. Returns ``(value_em, pdf_em, bs, weight, wo_world,
    redrawn)``; the light direction's value and pdf are those of the first
    pass, ``redrawn`` the lanes whose sample is the geometric frame's."""
    wi_world = si.to_world(si.wi)
    value_em = mi.Spectrum(0.0)                  # Light direction's BSDF value (first pass)
    pdf_em = mi.Float(0.0)                       # ... and its pdf
    bs = dr.zeros(mi.BSDFSample3f)               # Sampled direction (last pass)
    weight = mi.Spectrum(0.0)                    # ... its weight
    wo_world = mi.Vector3f(0.0)                  # ... and its world direction
    geometric = dr.zeros(mi.Bool, dr.width(wi_world))  # Lanes redrawing with the geometric frame
    redrawn = dr.zeros(mi.Bool, dr.width(wi_world))    # ... and those that did
    todo = mi.Bool(active)                       # Lanes with a pass still to run
    while todo:
        si_pass = mi.SurfaceInteraction3f(si)
        si_pass.sh_frame = dr.select(geometric, geo_frame, si.sh_frame)
        si_pass.wi = dr.select(geometric, si_pass.to_local(wi_world), si.wi)
        sample_1 = dr.select(geometric, redraws[0], samples[0])
        sample_2 = dr.select(geometric, redraws[1], samples[1])
        value, pdf, bs_pass, weight_pass = bsdf.eval_pdf_sample(ctx, si_pass, wo_em, sample_1, sample_2, todo)
        first = todo & ~geometric
        value_em = dr.select(first, value, value_em)
        pdf_em = dr.select(first, pdf, pdf_em)
        bs = dr.select(todo, bs_pass, bs)
        weight = dr.select(todo, weight_pass, weight)
        wo_world = dr.select(todo, si_pass.to_world(bs_pass.wo), wo_world)
        geometric = first & checked & contradicts(si, cos_in_geo, bs_pass, wo_world, weight_pass)
        redrawn |= geometric
        todo = geometric
    return value_em, pdf_em, bs, weight, wo_world, redrawn


def with_geometric_frame(si: mi.SurfaceInteraction3f, use: mi.Bool,
                         geo_frame: mi.Frame3f | None = None) -> mi.SurfaceInteraction3f:
    """``si`` with its shading frame replaced by the geometric normal where
    ``use`` is set (``wi`` re-expressed in the new frame); ``geo_frame``:
    ``mi.Frame3f(si.n)`` if the caller has it (else made here)."""
    si = mi.SurfaceInteraction3f(si)
    wi_world = si.to_world(si.wi)
    si.sh_frame = dr.select(use, mi.Frame3f(si.n) if geo_frame is None else geo_frame, si.sh_frame)
    # Only where the frame changes: elsewhere wi stays bit for bit, and a
    # missed ray's wi (a world direction, with no frame) stays what the
    # environment is looked up with
    si.wi = dr.select(use, si.to_local(wi_world), si.wi)
    return si
