"""``lathe_volpath``'s light-traced caustics (``caustics``): particles carry
the transmittance of the homogeneous media they cross (eqs. 32-40 of
docs/method.md with ``exp(-sigma_t * length)`` on every segment), combined
with volumetric path tracing by multiple importance sampling. The closed
form of an absorbing ball lens is in ``test_caustic_ball_lens.py``; here
the light tracer, path tracing and their mixture agree on coloured glass
that absorbs and scatters, seen directly and through a tinted pane (the
camera chains of eqs. 37-40 through a medium). And the surfaces that
emitter sampling's shadow rays cross (``null``, ``thindielectric``,
``mask``): weighted by their null transmission, and light through them
alone counted once (emitter sampling's, not a caustic path)."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from test_caustics import ball_scene, luminance

#: A coloured medium that absorbs and scatters (the ball's) and one that
#: only absorbs (the pane's): per unit length.
SCATTERING = {"type": "homogeneous", "albedo": {"type": "rgb", "value": [0.6, 0.3, 0.1]},
              "sigma_t": {"type": "rgb", "value": [0.2, 0.533, 1.0]}, "scale": 1.5}
ABSORBING = {"type": "homogeneous", "albedo": 0.0,
             "sigma_t": {"type": "rgb", "value": [1.0, 0.5, 0.25]}, "scale": 2.0}


def tinted_scene(pane: bool, kind: str = "polyline") -> mi.Scene:
    """``test_caustics``' ball (of ``kind``) over the floor under a small
    area light, the ball filled with :data:`SCATTERING`; with ``pane``,
    seen through a pane filled with :data:`ABSORBING`."""
    interiors = {"ball": SCATTERING, **({"pane": ABSORBING} if pane else {})}
    return ball_scene("area", pane=pane, interiors=interiors, kind=kind)


def render(scene: mi.Scene, spp: int, seed: int = 0, **params) -> np.ndarray:
    integrator = mi.load_dict({"type": "lathe_volpath", "max_depth": 12, **params})
    return luminance(np.array(mi.render(scene, integrator=integrator, spp=spp, seed=seed), dtype=np.float64))


@pytest.mark.parametrize(("pane", "kind"), [(False, "polyline"), (True, "polyline"), (True, "bspline"),
                                            (True, "catmull_rom")])
def test_caustics_through_media_agree_with_volumetric_path_tracing(pane, kind):
    """The caustic of a coloured ball that absorbs and scatters, on the floor
    seen directly or through a tinted pane (every camera connection then a
    solved chain through the pane's medium): nearly all weight on the light
    tracer (16 particles per camera sample, every blocked particle solving)
    against plain ``lathe_volpath`` at 8192 spp within 4% on the caustic
    and 1% on the image; the mixture of eqs. 32 and 40 with both weighing
    (1 particle per camera sample) within 4% of it. Measured: 2.0% and 0.5%,
    2.6% (no pane); through the pane over 8 seeds, light tracer 0.1415 +-
    0.0013, mixture 0.1430 +- 0.0014, plain 0.1464 +- 0.0021 (plain's
    caustic is heavy-tailed). And the caustic's error at 256 spp is under
    0.6 of plain's (measured: 0.25 without the pane). The ball is also a
    cubic B-spline and POV-Ray's Catmull-Rom curve, seen through the pane
    (the degree-6 kernels inside the medium, in the particles' chains and
    under the solved camera chains): the B-spline's image mean over 8
    renders within 0.13% of plain's."""
    scene = tinted_scene(pane, kind)
    plain = np.mean([render(scene, 2048, seed=s, caustics=False) for s in range(4)], axis=0)
    # (the B-spline ball's highlight of the light, a few pixels, is path
    # traced alike in both and makes a 64 spp render's mean scatter by 1.1%:
    # 8 renders there, whose mean is within 0.13% of plain's)
    many = np.mean([render(scene, 64, seed=30 + s, caustic_paths=16.0, caustic_camera_chains=1.0)
                    for s in range(2 if kind == "polyline" else 8)], axis=0)
    # (the region from renders of their own: chosen by the noise of `many`,
    # it would favour its bright pixels)
    caustic = render(scene, 64, seed=99, caustic_paths=16.0) - render(scene, 64, seed=99, caustics=False)
    region = caustic > 0.2 * render(scene, 256, seed=98, caustics=False)
    assert region.sum() >= 20, "the caustic must be on the film"
    assert many[region].mean() == pytest.approx(plain[region].mean(), rel=0.04)
    assert many.mean() == pytest.approx(plain.mean(), rel=0.01)
    balanced = np.mean([render(scene, 64, seed=40 + s, caustic_paths=1.0) for s in range(4)], axis=0)
    assert balanced[region].mean() == pytest.approx(many[region].mean(), rel=0.04)
    plain_256 = render(scene, 256, seed=12, caustics=False)
    traced_256 = render(scene, 256, seed=12)
    assert np.abs(traced_256 - plain)[region].mean() < 0.6 * np.abs(plain_256 - plain)[region].mean()


@pytest.mark.parametrize("case", ["grid medium", "sensor in a medium", "light in a medium"])
def test_caustics_left_to_path_tracing_where_media_do_not_allow(case):
    """Eq. 44 needs homogeneous media and a camera and lights outside every
    medium: otherwise the light tracer is not set up (saying why) and the
    render is plain ``lathe_volpath``'s, bit for bit."""
    scene = ball_scene("point", res=16)
    shapes = {shape.id(): shape for shape in scene.shapes()}
    fog = {"type": "homogeneous", "sigma_t": 0.01}
    sensor = {"type": "perspective", "fov": 45,
              "to_world": mi.ScalarTransform4f().look_at(origin=[0, -5, 4], target=[0, 0, 0.6], up=[0, 0, 1]),
              "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}}}
    light = {"type": "point", "position": [0.3, 3.0, 5.0], "intensity": {"type": "rgb", "value": [40.0] * 3}}
    ball = {"type": "lathe", "profile": "0 0, 1 1, 0 2", "bsdf": {"type": "dielectric"}}
    expected = {
        "grid medium": "caustics need homogeneous media (medium 'interior' of shape 'ball' is not)",
        "sensor in a medium": "caustics need a sensor outside every medium (the sensor has a medium)",
        "light in a medium": "caustics need lights outside every medium (emitter 'light' has a medium)",
    }
    if case == "grid medium":
        grid = mi.VolumeGrid(np.full((2, 2, 2, 1), 0.5, dtype=np.float32))
        ball["interior"] = {"type": "heterogeneous", "sigma_t": {"type": "gridvolume", "grid": grid}}
    elif case == "sensor in a medium":
        sensor["medium"] = fog
    else:
        light["medium"] = fog
    scene = mi.load_dict({"type": "scene", "sensor": sensor, "floor": shapes["floor"], "ball": ball,
                          "light": light})
    integrator = mi.load_dict({"type": "lathe_volpath"})
    tracer, why = integrator.caustic_setup(scene, scene.sensors()[0])
    assert tracer is None and why == expected[case]
    on = np.array(mi.render(scene, integrator=integrator, spp=4, seed=2))
    off = np.array(mi.render(scene, integrator=mi.load_dict({"type": "lathe_volpath", "caustics": False}),
                             spp=4, seed=2))
    assert np.array_equal(on, off)


def test_parameter_errors_name_lathe_volpath():
    with pytest.raises(Exception) as error:
        mi.load_dict({"type": "lathe_volpath", "caustic_paths": -1.0})
    assert ("lathe_volpath: parameter 'caustic_paths' must be > 0 and below 1e6 (particles per camera "
            "sample); got -1.0") in str(error.value)
    with pytest.raises(Exception) as error:
        mi.load_dict({"type": "lathe_volpath", "caustic_max_chain": 0})
    assert "lathe_volpath: parameter 'caustic_max_chain' must be >= 1; got 0" in str(error.value)


def test_caustics_when_an_aov_integrator_wraps_lathe_volpath():
    """Mitsuba's ``aov`` integrator (the turntable's denoiser guides for an
    integrator without guides of its own) calls ``render`` from C++ with
    the seed as a ``UInt32``: the caustic pass takes it (it used to stop
    with a Dr.Jit error), and the RGB channels are the plain render's."""
    scene = tinted_scene(pane=False)
    integrator = mi.load_dict({"type": "lathe_volpath", "max_depth": 12})
    wrapped = mi.load_dict({"type": "aov", "aovs": "albedo:albedo,nn:sh_normal", "integrator": integrator})
    guided = np.array(mi.render(scene, integrator=wrapped, spp=8, seed=4), dtype=np.float64)
    direct = np.array(mi.render(scene, integrator=integrator, spp=8, seed=4), dtype=np.float64)
    plain = np.array(mi.render(scene, integrator=mi.load_dict({"type": "lathe_volpath", "max_depth": 12,
                                                               "caustics": False}), spp=8, seed=4))
    assert guided.shape[-1] == direct.shape[-1] + 6
    assert np.allclose(guided[..., :3], direct[..., :3], rtol=1e-5, atol=1e-6)
    assert np.abs(direct[..., :3] - plain[..., :3]).max() > 0.1  # (the caustic is in it)


# ---------------------------------------------------------------------------
# Surfaces that shadow rays cross (null, thindielectric, mask)
# ---------------------------------------------------------------------------

#: The sheet scene's point light: position and intensity.
SHEET_LIGHT = (np.array([0.0, 0.0, 10.0]), 100.0)


def sheet_scene(bsdf: dict | None, closed: bool = False, light: str = "point", res: int = 32) -> mi.Scene:
    """A lathe disc of radius 2 at z = 3 with the BSDF ``bsdf`` (none: no
    disc), an open sheet or, with ``closed``, a slab 0.4 thick, over a grey
    floor (reflectance 0.5), lit from straight above by :data:`SHEET_LIGHT`
    or (``light="sphere"``) a sphere light of radius 0.5 there (radiance
    40), seen obliquely: the floor under the disc on the film's lower half,
    through the disc on its upper half."""
    scene = {
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, -12, 10], target=[0, 0, 0],
                                                              up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}}},
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale([20, 20, 1]),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}},
    }
    position, intensity = SHEET_LIGHT
    if light == "point":
        scene["light"] = {"type": "point", "position": position.tolist(),
                          "intensity": {"type": "rgb", "value": intensity}}
    else:
        scene["light"] = {"type": "sphere", "center": position.tolist(), "radius": 0.5,
                          "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 40.0}}}
    if bsdf is not None:
        scene["disc"] = {"type": "lathe", "profile": "0 -0.2, 2 -0.2, 2 0.2, 0 0.2" if closed else "0 0, 2 0",
                         "open": not closed, "to_world": mi.ScalarTransform4f().translate([0, 0, 3]),
                         "bsdf": bsdf}
    return mi.load_dict(scene)


def under_sheet(scene: mi.Scene, margin: float = 0.15) -> tuple[np.ndarray, np.ndarray]:
    """The floor pixels of :func:`sheet_scene`'s film lit through the disc
    and seen past it (``margin`` off its rim both ways, at the pixel
    centres), and the cosine of the angle at which their floor point sees
    the light (H, W each)."""
    sensor = scene.sensors()[0]
    res = sensor.film().crop_size()
    x, y = np.meshgrid((np.arange(res.x) + 0.5) / res.x, (np.arange(res.y) + 0.5) / res.y)
    ray = sensor.sample_ray(0.0, 0.5, mi.Point2f(x.ravel(), y.ravel()), mi.Point2f(0.5))[0]
    o = np.array([ray.o.x, ray.o.y, ray.o.z])
    o = o.reshape(3, -1) if o.ndim == 2 else o[:, None]
    d = np.array([ray.d.x, ray.d.y, ray.d.z])
    floor = o + d * (-o[2] / d[2])
    to_light = SHEET_LIGHT[0][:, None] - floor
    lit_at = floor + to_light * ((2.8 - floor[2]) / to_light[2])  # (both faces of a slab)
    lit_top = floor + to_light * ((3.2 - floor[2]) / to_light[2])
    seen_at = o + d * ((3.2 - o[2]) / d[2])
    seen_low = o + d * ((2.8 - o[2]) / d[2])
    inside = np.maximum(np.hypot(lit_at[0], lit_at[1]), np.hypot(lit_top[0], lit_top[1])) < 2.0 - margin
    past = np.minimum(np.hypot(seen_at[0], seen_at[1]), np.hypot(seen_low[0], seen_low[1])) > 2.0 + margin
    cos = to_light[2] / np.linalg.norm(to_light, axis=0)
    return (inside & past).reshape(res.y, res.x), cos.reshape(res.y, res.x)


def null_transmission(bsdf: dict, cos: np.ndarray) -> np.ndarray:
    """Mitsuba's ``eval_null_transmission`` of ``bsdf`` for light arriving
    at ``cos`` to its normal (a surface at rest, uv (0.5, 0.5))."""
    instance = mi.load_dict(bsdf)
    si = dr.zeros(mi.SurfaceInteraction3f, cos.size)
    si.sh_frame = mi.Frame3f(mi.Vector3f(0.0, 0.0, 1.0))
    si.uv = mi.Point2f(0.5)
    c = cos.ravel().astype(np.float32)
    si.wi = mi.Vector3f(np.sqrt(1.0 - c * c), 0.0, c)
    value = instance.eval_null_transmission(si).x + dr.zeros(mi.Float, cos.size)  # (a constant: width 1)
    return np.array(value).reshape(cos.shape)


def rgb_mean(image) -> np.ndarray:
    """The mean of an RGB render's colour channels (H, W)."""
    return np.array(image, dtype=np.float64)[..., :3].mean(axis=-1)


@pytest.mark.parametrize("bsdf", [{"type": "thindielectric"},
                                  {"type": "mask", "opacity": 0.3, "bsdf": {"type": "diffuse"}}],
                         ids=["thindielectric", "mask"])
def test_shadow_rays_carry_the_null_transmission_of_what_they_cross(bsdf):
    """Emitter sampling through a surface with a ``Null`` lobe is weighted
    by its ``eval_null_transmission``, as in Mitsuba's ``volpath``: direct
    light alone (``max_depth`` 2: no caustic chain either) on the floor
    under an open disc, per pixel, is the same pixel without the disc
    times the closed form: a ``thindielectric`` sheet's transmittance
    ``1 - 2R / (1 + R)`` at the angle to the light (0.92 straight down),
    ``1 - opacity`` for a ``mask``. Within 0.1% per pixel (measured: 0.001%;
    the same seed draws the same pixel positions with and without the
    disc). The shadow rays used to cross them unweighted: the floor under a
    ``thindielectric`` sheet 8% too bright, under the mask 43%."""
    integrator = mi.load_dict({"type": "lathe_volpath", "max_depth": 2})
    scene = sheet_scene(bsdf)
    region, cos = under_sheet(scene)
    assert region.sum() >= 30
    with_disc = rgb_mean(mi.render(scene, integrator=integrator, spp=16, seed=1))
    without = rgb_mean(mi.render(sheet_scene(None), integrator=integrator, spp=16, seed=1))
    expected = null_transmission(bsdf, cos)
    assert np.abs(with_disc / without / expected - 1.0)[region].max() < 1e-3


@pytest.mark.parametrize(("bsdf", "closed", "light"), [("null", False, "point"),
                                                       ("thindielectric", False, "point"),
                                                       ("thindielectric", True, "sphere")])
def test_light_through_null_crossings_is_counted_once(bsdf, closed, light):
    """Emitter sampling's shadow rays cross ``null`` surfaces and a
    ``thindielectric``'s transmission (its ``Null`` lobe): a path from the
    floor to the light through such crossings alone is emitter sampling's,
    not a caustic path, and the light tracer does not splat it (eq. 32).
    The floor under an open ``null`` or ``thindielectric`` disc lit by a
    point light, and under a closed ``thindielectric`` slab lit by a sphere
    light, with caustics (the default) against Mitsuba's ``volpath`` on the
    lathe's reference mesh: within 1% (point: emitter sampling alone, 0.1%
    apart over 4 seeds) and 3% (sphere, 4096 spp: the rim's reflected ring
    is path traced on the mesh; 0.55% standard deviation over 8 seeds).
    Both techniques counted it: 2.0x, 2.07x and 2.08x as bright."""
    spp = 64 if light == "point" else 4096
    scene = sheet_scene({"type": bsdf}, closed=closed, light=light)
    region, _ = under_sheet(scene)
    ours = rgb_mean(mi.render(scene, integrator=mi.load_dict({"type": "lathe_volpath", "max_depth": 12}),
                              spp=spp, seed=2))
    stock = rgb_mean(mi.render(scene, integrator=mi.load_dict({"type": "volpath", "max_depth": 12}),
                               spp=spp, seed=3))
    assert ours[region].mean() == pytest.approx(stock[region].mean(), rel=0.01 if light == "point" else 0.03)
