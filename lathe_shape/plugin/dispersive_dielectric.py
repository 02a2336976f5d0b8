"""The ``dispersive_dielectric`` BSDF: a smooth dielectric interface whose
interior index of refraction depends on the wavelength (dispersion, the
"fire" of cut crystal; parameters: :class:`DispersiveDielectric`).

Smooth (Dirac delta) reflection and refraction weighted by the unpolarized
Fresnel reflectance, as Mitsuba's ``dielectric``: the interior index is
``n(lambda)``, so the relative index ``eta = n(lambda) / ext_ior`` is
wavelength dependent.

**Spectral variants only.** Mitsuba's spectral variants carry four
wavelengths per path (``si.wavelengths``; the sensor draws them so that
each one alone is uniformly distributed over the visible range). A
delta refraction can follow only one direction, so where the index
varies across the path's wavelengths this BSDF picks one of them at each
interface, uniformly at random (from ``sample2``, which a delta BSDF does
not otherwise use): the *hero wavelength*. The choice between reflection
and refraction is made with the hero's Fresnel reflectance R_0; a
reflection keeps every wavelength (the reflected direction does not depend
on the index), with weights R_i / R_0; a refraction follows the hero's
direction and keeps only the hero, with its weight multiplied by the
number of wavelengths (4) and the other wavelengths' weights set to zero.
Each wavelength is the hero with probability 1/4 at every interface, so
the estimate is unbiased without state carried along the path; a later
dispersive refraction that picks a wavelength already dropped ends the
path's contribution (noise after the first dispersive refraction).
``bs.eta`` is the hero's relative index. With a constant index (``int_ior`` a float without ``abbe``) nothing
is dropped. RGB and monochrome variants have no wavelengths: the plugin
refuses them, naming the spectral variants (``llvm_ad_spectral``,
``cuda_ad_spectral``); polarized variants are refused as well.
"""

from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi

from .variants import register_jit_plugin

__all__ = ["DispersiveDielectric", "GLASSES", "LINES", "abbe_number", "cauchy_from_abbe", "register",
           "sellmeier_index"]

#: Fraunhofer lines (nm) that define n_F, n_d, n_C and the Abbe number.
LINES = {"F": 486.13, "d": 587.56, "C": 656.27}

#: Sellmeier coefficients (B1, B2, B3), (C1, C2, C3) [um^2] of named glasses:
#: Schott's catalogue for N-BK7, F2 and SF11; Malitson (1965) for fused silica.
GLASSES: dict[str, tuple[tuple[float, float, float], tuple[float, float, float]]] = {
    "bk7": ((1.03961212, 0.231792344, 1.01046945), (0.00600069867, 0.0200179144, 103.560653)),
    "f2": ((1.34533359, 0.209073176, 0.937357162), (0.00997743871, 0.0470450767, 111.886764)),
    "sf11": ((1.73759695, 0.313747346, 1.89878101), (0.013188707, 0.0623068142, 155.23629)),
    "fused_silica": ((0.6961663, 0.4079426, 0.8974794), (0.0046791482, 0.0135120631, 97.9340025)),
}

#: Wavelength range (nm) over which an index must be real and positive:
#: Mitsuba's spectral range.
CHECKED_RANGE = (360.0, 830.0)

WHO = "dispersive_dielectric"


def sellmeier_index(wavelength_nm, b, c):
    """The Sellmeier index at ``wavelength_nm`` (a number or a Dr.Jit array)."""
    l2 = dr.square(wavelength_nm * 1e-3)
    n2 = 1.0 + sum(bi * l2 / (l2 - ci) for bi, ci in zip(b, c, strict=True))
    return dr.sqrt(n2) if not isinstance(n2, float) else math.sqrt(n2)


def cauchy_from_abbe(n_d: float, abbe: float) -> tuple[float, float]:
    """(A, B [nm^2]) of Cauchy's n = A + B / lambda^2 through n_d at the d
    line with (n_d - 1) / (n_F - n_C) = ``abbe``."""
    spread = (n_d - 1.0) / abbe  # n_F - n_C
    b = spread / (LINES["F"] ** -2 - LINES["C"] ** -2)
    return n_d - b / LINES["d"] ** 2, b


def abbe_number(index) -> float:
    """V_d of an index function ``index(lambda_nm)``."""
    return (index(LINES["d"]) - 1.0) / (index(LINES["F"]) - index(LINES["C"]))


def _float_or_string(props: mi.Properties, name: str):
    """``props[name]`` as a float (``<float>`` or ``<integer>``) or a str."""
    value = props.get(name)
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise ValueError(f"{WHO}: parameter '{name}' must be given as <float> or <string>, got {value!r}")
    return float(value) if isinstance(value, int) else value


def _three_values(props: mi.Properties, name: str) -> tuple[float, float, float]:
    value = props.get(name)
    if not isinstance(value, str):
        raise ValueError(f"{WHO}: parameter '{name}' must be a <string> of three comma-separated "
                         f"values, got {value!r}")
    try:
        values = tuple(float(v) for v in value.replace(",", " ").split())
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise ValueError(f"{WHO}: parameter '{name}' must hold three comma-separated finite numbers, "
                         f"got '{value}'")
    return values


def _glass(name: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    key = name.strip().lower().replace("-", "_").replace(" ", "_")
    aliases = {"n_bk7": "bk7", "nbk7": "bk7", "silica": "fused_silica", "fused_quartz": "fused_silica"}
    key = aliases.get(key, key)
    if key not in GLASSES:
        raise ValueError(f"{WHO}: parameter 'int_ior': unknown glass '{name}' (known glasses: "
                         f"{', '.join(GLASSES)}; or give n_d as a <float> with 'abbe', or "
                         "'sellmeier_b' and 'sellmeier_c')")
    return GLASSES[key]


def _exterior_index(props: mi.Properties) -> float:
    """``ext_ior`` as Mitsuba's ``dielectric`` reads it (its own table of
    named materials, by loading one with that exterior)."""
    if "ext_ior" not in props:
        value: float | str = "air"
    else:
        value = _float_or_string(props, "ext_ior")
    if isinstance(value, float):
        if not (math.isfinite(value) and value > 0.0):
            raise ValueError(f"{WHO}: parameter 'ext_ior' must be a positive index, got {value:g}")
        return value
    try:
        reference = mi.load_dict({"type": "dielectric", "int_ior": 1.0, "ext_ior": value})
    except Exception as error:  # Mitsuba's message: unknown material
        raise ValueError(f"{WHO}: parameter 'ext_ior': unknown material '{value}' (Mitsuba's dielectric: "
                         f"{str(error).strip().splitlines()[-1]})") from None
    eta = mi.traverse(reference)["eta"]
    return 1.0 / float(eta if isinstance(eta, (int, float)) else dr.ravel(eta)[0])


def _fresnel(cos_i, eta):
    """Unpolarized Fresnel reflectance of a smooth interface of relative
    index ``eta`` (interior over exterior) for ``cos_i`` (positive on the
    exterior side), elementwise over ``eta``'s wavelengths: returns
    (R, cos_t (signed, opposite to cos_i), eta_it, eta_ti)."""
    outside = cos_i >= 0.0
    eta_it = dr.select(outside, eta, dr.rcp(eta))  # n_transmitted / n_incident
    eta_ti = dr.rcp(eta_it)
    cos_t2 = 1.0 - (1.0 - dr.square(cos_i)) * dr.square(eta_ti)
    ci = dr.abs(cos_i)
    ct = dr.safe_sqrt(cos_t2)
    rs = (ci - eta_it * ct) / (ci + eta_it * ct)
    rp = (eta_it * ci - ct) / (eta_it * ci + ct)
    r = dr.select(cos_t2 <= 0.0, 1.0, 0.5 * (dr.square(rs) + dr.square(rp)))
    r = dr.select(eta == 1.0, 0.0, r)
    return r, dr.select(outside, -ct, ct), eta_it, eta_ti


class DispersiveDielectric(mi.BSDF):
    """Smooth dielectric with a wavelength-dependent interior index.

    .. pluginparameters::

     * - int_ior
       - |float| or |string|
       - Interior index. A ``<float>`` is n_d, the index at the helium d line
         (587.56 nm); with ``abbe`` the index follows Cauchy's law through
         n_F, n_d and n_C, without it the index is constant (no dispersion).
         A ``<string>`` names a glass of :data:`GLASSES` (``bk7``, ``f2``,
         ``sf11``, ``fused_silica``; case and ``-``/``_`` ignored), given by
         its Sellmeier coefficients. (Default: ``bk7`` when neither form of
         ``sellmeier_b``/``sellmeier_c`` is given)

     * - abbe
       - |float|
       - Abbe number V_d = (n_d - 1) / (n_F - n_C) of a ``<float>`` ``int_ior``
         (positive; crown glass about 64, dense flint about 25).

     * - sellmeier_b, sellmeier_c
       - |string|
       - The interior index as the Sellmeier equation
         n^2 = 1 + sum_i B_i lambda^2 / (lambda^2 - C_i), lambda in micrometres,
         C_i in square micrometres: three comma-separated values each (both
         are needed; not together with ``int_ior``/``abbe``).

     * - ext_ior
       - |float| or |string|
       - Exterior index, constant, as for Mitsuba's ``dielectric``: a number
         or a material name (``air``, ``water``, ``vacuum``, ...; Mitsuba's
         own table). (Default: ``air``)
    """

    def __init__(self, props: mi.Properties) -> None:
        super().__init__(props)
        if not mi.is_spectral or mi.is_polarized:
            kind = "polarized" if mi.is_polarized else "RGB/monochrome"
            raise RuntimeError(
                f"{WHO}: Mitsuba variant '{mi.variant()}' is {kind}: dispersion needs a path's "
                "wavelengths, which only the unpolarized spectral variants carry; use "
                "'llvm_ad_spectral' (or 'cuda_ad_spectral'), e.g. lathe-render --variant llvm_ad_spectral"
            )
        def has(name: str) -> bool:
            return name in props

        sellmeier = has("sellmeier_b") or has("sellmeier_c")
        if sellmeier and (has("int_ior") or has("abbe")):
            given = [n for n in ("int_ior", "abbe") if has(n)]
            raise ValueError(f"{WHO}: give the interior index one way: parameter(s) "
                             f"{', '.join(map(repr, given))} and 'sellmeier_b'/'sellmeier_c' were both given")
        if sellmeier:
            if not (has("sellmeier_b") and has("sellmeier_c")):
                missing = "sellmeier_c" if has("sellmeier_b") else "sellmeier_b"
                raise ValueError(f"{WHO}: parameter '{missing}' is missing (the Sellmeier form needs "
                                 "both 'sellmeier_b' and 'sellmeier_c')")
            self._set_sellmeier(_three_values(props, "sellmeier_b"), _three_values(props, "sellmeier_c"),
                                "'sellmeier_b'/'sellmeier_c'")
        else:
            value = _float_or_string(props, "int_ior") if has("int_ior") else "bk7"
            if isinstance(value, str):
                if has("abbe"):
                    raise ValueError(f"{WHO}: parameter 'abbe' goes with a numeric 'int_ior' (n_d); "
                                     f"the glass '{value}' has its own dispersion")
                self._set_sellmeier(*_glass(value), f"glass '{value}'")
            else:
                self._set_abbe(value, _float_or_string(props, "abbe") if has("abbe") else None)
        self.ext_ior = _exterior_index(props)
        flags = mi.BSDFFlags.FrontSide | mi.BSDFFlags.BackSide
        self.m_components = [mi.BSDFFlags.DeltaReflection | flags,
                             mi.BSDFFlags.DeltaTransmission | flags | mi.BSDFFlags.NonSymmetric]
        self.m_flags = self.m_components[0] | self.m_components[1]

    def _set_sellmeier(self, b, c, what: str) -> None:
        self.form = "sellmeier"
        self.b, self.c = tuple(b), tuple(c)
        self.dispersive = True
        lo, hi = CHECKED_RANGE
        for step in range(0, 471):
            lam = lo + (hi - lo) * step / 470
            l2 = (lam * 1e-3) ** 2
            if any(abs(l2 - ci) < 1e-12 for ci in self.c):
                n2 = math.inf
            else:
                n2 = 1.0 + sum(bi * l2 / (l2 - ci) for bi, ci in zip(self.b, self.c, strict=True))
            if not (math.isfinite(n2) and n2 > 0.0):
                raise ValueError(f"{WHO}: the Sellmeier index of {what} is not a positive real number "
                                 f"at {lam:g} nm (n^2 = {n2:g}); check the coefficients (C in um^2)")

    def _set_abbe(self, n_d: float, abbe: float | str | None) -> None:
        if not (math.isfinite(n_d) and n_d > 0.0):
            raise ValueError(f"{WHO}: parameter 'int_ior' must be a positive index, got {n_d:g}")
        self.form = "cauchy"
        if abbe is None:
            self.cauchy = (n_d, 0.0)
            self.dispersive = False
            return
        if isinstance(abbe, str) or not (math.isfinite(abbe) and abbe > 0.0):
            raise ValueError(f"{WHO}: parameter 'abbe' must be a positive number, got {abbe!r}")
        if n_d <= 1.0:
            raise ValueError(f"{WHO}: parameter 'abbe' needs 'int_ior' > 1 (the Abbe number is "
                             f"(n_d - 1) / (n_F - n_C)), got int_ior {n_d:g}")
        self.cauchy = cauchy_from_abbe(n_d, abbe)
        self.dispersive = True

    def index(self, wavelength_nm):
        """Interior index at ``wavelength_nm`` (number or Dr.Jit array)."""
        if self.form == "sellmeier":
            return sellmeier_index(wavelength_nm, self.b, self.c)
        a, b = self.cauchy
        return a + b / dr.square(wavelength_nm) if b else a + 0.0 * wavelength_nm

    def sample(self, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f, sample1: mi.Float,
               sample2: mi.Point2f, active: mi.Bool = True) -> tuple[mi.BSDFSample3f, mi.Spectrum]:
        cos_i = mi.Frame3f.cos_theta(si.wi)
        eta = mi.Spectrum(self.index(si.wavelengths)) / self.ext_ior
        r, cos_t, eta_it, eta_ti = _fresnel(cos_i, eta)
        count = dr.size_v(mi.Spectrum)
        if self.dispersive:
            # The hero: one of the path's wavelengths, uniformly at random
            # (sample2 is free: a delta BSDF does not use it)
            hero = dr.minimum(mi.UInt32(sample2.x * count), count - 1)
            one_hot = dr.zeros(mi.Spectrum)
            for slot in range(count):
                one_hot[slot] = dr.select(hero == slot, 1.0, 0.0)
        else:
            hero, one_hot = mi.UInt32(0), None

        def of_hero(values):
            if one_hot is None:
                return values[0]
            return dr.sum(values * one_hot)  # the hero's component

        r0, cos_t0, eta_it0, eta_ti0 = of_hero(r), of_hero(cos_t), of_hero(eta_it), of_hero(eta_ti)
        t0 = 1.0 - r0
        has_r = ctx.is_enabled(mi.BSDFFlags.DeltaReflection, 0)
        has_t = ctx.is_enabled(mi.BSDFFlags.DeltaTransmission, 1)

        bs = dr.zeros(mi.BSDFSample3f)
        if has_r and has_t:
            selected_r = (sample1 <= r0) & active
            bs.pdf = dr.detach(dr.select(selected_r, r0, t0))
            # Each wavelength's weight relative to the hero's probability
            weight_r = r / dr.maximum(r0, 1e-30)
            weight_t = (1.0 - r) / dr.maximum(t0, 1e-30)
        elif has_r or has_t:
            selected_r = mi.Bool(has_r) & active
            bs.pdf = mi.Float(1.0)
            weight_r, weight_t = r, 1.0 - r
        else:
            return bs, mi.Spectrum(0.0)
        selected_t = ~selected_r & active
        if one_hot is not None:
            # Only the hero follows its refracted direction; drawn with
            # probability 1/count, it carries count times its weight
            weight_t = weight_t * one_hot * count

        bs.wo = dr.select(selected_r, mi.reflect(si.wi), mi.refract(si.wi, cos_t0, eta_ti0))
        bs.eta = dr.select(selected_r, 1.0, eta_it0)
        bs.sampled_component = dr.select(selected_r, mi.UInt32(0), mi.UInt32(1))
        bs.sampled_type = dr.select(selected_r, mi.UInt32(+mi.BSDFFlags.DeltaReflection),
                                    mi.UInt32(+mi.BSDFFlags.DeltaTransmission))
        weight = mi.Spectrum(dr.select(selected_r, mi.Spectrum(weight_r), mi.Spectrum(weight_t)))
        if ctx.mode == mi.TransportMode.Radiance:
            # Radiance is compressed into the smaller solid angle on the denser side
            weight = dr.select(selected_t, weight * dr.square(eta_ti0), weight)
        return bs, dr.select(active & (bs.pdf > 0.0), weight, 0.0)

    def eval(self, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f, wo: mi.Vector3f,
             active: mi.Bool = True) -> mi.Spectrum:
        return mi.Spectrum(0.0)

    def pdf(self, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f, wo: mi.Vector3f,
            active: mi.Bool = True) -> mi.Float:
        return mi.Float(0.0)

    def eval_pdf(self, ctx: mi.BSDFContext, si: mi.SurfaceInteraction3f, wo: mi.Vector3f,
                 active: mi.Bool = True) -> tuple[mi.Spectrum, mi.Float]:
        return mi.Spectrum(0.0), mi.Float(0.0)

    def traverse(self, callback) -> None:
        pass

    def to_string(self) -> str:
        if self.form == "sellmeier":
            what = f"sellmeier_b={self.b}, sellmeier_c={self.c}"
        else:
            what = f"cauchy A={self.cauchy[0]:.6g}, B={self.cauchy[1]:.6g} nm^2"
        n_d = self.index(LINES["d"])
        return (f"DispersiveDielectric[{what}, n_d={float(n_d):.5f}, ext_ior={self.ext_ior:g}, "
                f"dispersive={self.dispersive}]")


def register() -> None:
    """Register ``<bsdf type="dispersive_dielectric">`` for the active variant."""
    register_jit_plugin(mi.register_bsdf, "dispersive_dielectric", DispersiveDielectric,
                        lambda props: f"{WHO} '{props.id()}'" if props.id() else WHO)
