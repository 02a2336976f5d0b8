"""The light-traced caustics (``caustics``) and what the camera, the film and
the scene's size ask of them: a perspective camera's clip range (a point
out of it is not seen, and what it clips away occludes nothing, for the
straight connection and for the camera-chain solves), a principal point
offset, directional and environment particles in a scene of huge extent,
films that develop XYZ, and the limit on the number of particles.

The scene: test_caustics.py's glass ball on a floor, a point light (whose
caustic the light tracer alone finds: comparisons are exact up to float
rounding) unless said otherwise, 48x48."""

from __future__ import annotations

import math

import mitsuba as mi
import numpy as np
import pytest
from test_caustics import BALL, luminance

T = mi.ScalarTransform4f
CAMERA, TARGET = np.array([0.0, -5.0, 4.0]), np.array([0.0, 0.0, 0.6])
RES = 48
#: A camera's film twice as wide and as high, with the same pixels (a crop
#: of it is the 48x48 camera, shifted)
WIDE_FOV = 2.0 * math.degrees(math.atan(2.0 * math.tan(math.radians(22.5))))
SUN = {"sun": {"type": "directional", "direction": [0.1, -0.4, -1.0],
               "irradiance": {"type": "rgb", "value": 5.0}}}
BLACK = {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.0}}


def view(distance: float) -> list[float]:
    """The point ``distance`` from the camera towards its target."""
    return (CAMERA + distance * (TARGET - CAMERA) / np.linalg.norm(TARGET - CAMERA)).tolist()


def scene(sensor: dict | None = None, film: dict | None = None, light: str = "point", sky: bool = True,
          pane: bool = False, extra: dict | None = None) -> mi.Scene:
    """The glass ball (radius 1, 0.2 above the floor) seen from (0, -5, 4),
    fov 45; ``sensor``, ``film``: parameters over the defaults; ``light``:
    ``point`` (intensity 40 from above, behind the ball), ``area`` (the
    same from a small square) or ``none``; ``sky``: a constant 0.05;
    ``pane``: a glass pane 1.5 from the camera that fills the view (the
    floor seen only through it); ``extra``: more scene objects."""
    scene = {
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 45,
                   "to_world": T().look_at(origin=CAMERA.tolist(), target=TARGET.tolist(), up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": RES, "height": RES, "rfilter": {"type": "box"},
                            **(film or {})},
                   "sampler": {"type": "independent"}, **(sensor or {})},
        "floor": {"type": "rectangle", "to_world": T().scale([8, 8, 1]),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.7}}},
        "ball": {"type": "lathe", "profile": BALL, "mesh_segments": 128,
                 "bsdf": {"type": "dielectric", "int_ior": 1.33}},
    }
    if sky:
        scene["sky"] = {"type": "constant", "radiance": {"type": "rgb", "value": 0.05}}
    if light == "point":
        scene["light"] = {"type": "point", "position": [0.3, 3.0, 5.0],
                          "intensity": {"type": "rgb", "value": 40.0}}
    elif light == "area":
        scene["light"] = {"type": "rectangle",
                          "to_world": T().translate([0.3, 3.0, 5.0]).scale([0.25, 0.25, 1])
                          @ T().rotate([1, 0, 0], 145),
                          "emitter": {"type": "area", "radiance": {"type": "rgb", "value": 160.0}}}
    if pane:
        scene["pane"] = {"type": "lathe", "profile": "0 -0.05, 1.5 -0.05, 1.5 0.05, 0 0.05",
                         "to_world": T().look_at(origin=view(1.5), target=CAMERA.tolist(), up=[0, 0, 1]),
                         "bsdf": {"type": "dielectric", "int_ior": 1.5}}
    scene.update(extra or {})
    return mi.load_dict(scene)


def render(scene: mi.Scene, spp: int, seed: int = 0, kind: str = "lathe_path", **params) -> np.ndarray:
    integrator = mi.load_dict({"type": kind, "max_depth": 12, **params})
    return np.array(mi.render(scene, integrator=integrator, spp=spp, seed=seed), dtype=np.float64)


def caustic(scene: mi.Scene, per_pixel: int = 64, seed: int = 7) -> np.ndarray:
    """The light tracer's caustic alone (weight 1), luminance (H, W)."""
    from lathe_shape.validation.caustics_bench import caustic_image

    return luminance(caustic_image(scene, per_pixel, seed))


# ---------------------------------------------------------------- clip range

@pytest.mark.parametrize("pane", [False, True])
def test_far_clip_hides_the_caustic_beyond_it(pane):
    """Mitsuba's camera rays end at depth ``far_clip`` (along the viewing
    direction): beyond it the camera sees the sky, 0.05 exactly. The
    caustic there must not be splatted: straight (far_clip 5.5 cuts the
    floor under the ball, where more than half of the caustic lies) or,
    behind a pane 1.5 from the camera, through the chain the solver finds
    (far_clip 1.4 cuts the pane too: the whole image is sky). Before, the
    straight connection read the sensor's importance, which Mitsuba does
    not clip (only its pdf), and the solver did not clip the chain's first
    segment: 4.6 and 8.5 over the sky's 0.05."""
    far = 1.4 if pane else 5.5
    clipped_scene = scene({"far_clip": far}, pane=pane)
    off = render(clipped_scene, 16, seed=1, caustics=False)
    clipped = np.all(np.abs(off[..., :3] - 0.05) < 1e-6, axis=-1)
    unclipped = caustic(scene(pane=pane))
    assert unclipped[clipped].sum() > 0.4 * unclipped.sum() > 10.0  # (the caustic is there)
    on = render(clipped_scene, 16, seed=1)
    np.testing.assert_allclose(on[clipped][:, :3], 0.05, atol=1e-6)


@pytest.mark.parametrize("pane", [False, True])
def test_near_clip_ignores_what_it_cuts_away(pane):
    """Mitsuba's camera rays start at depth ``near_clip``: a black wall 0.6
    in front of the camera, cut away by near_clip 1, hides nothing (no sky:
    it blocks no light either). The caustic must be the one without the wall
    (the same particles: equal up to rounding), straight or through the
    pane (1.5 from the camera, inside the clip range). Before, the
    connection's shadow ray and the solver's chain met the wall: the caustic
    region read 0.0007 and 0.003 instead of 0.28 and 0.29."""
    place = T().look_at(origin=view(0.6), target=TARGET.tolist(), up=[0, 0, 1]) @ T().scale(3)
    wall = {"wall": {"type": "rectangle", "bsdf": BLACK, "to_world": place}}
    walled = render(scene({"near_clip": 1.0}, pane=pane, sky=False, extra=wall), 16, seed=2)
    plain = render(scene(pane=pane, sky=False), 16, seed=2)
    region = caustic(scene(pane=pane, sky=False)) > 0.2 * luminance(plain)
    assert region.sum() >= 20
    # (measured: 6e-8 and 7e-5 apart, the rays starting 0.01 or 1 from the
    # camera)
    assert luminance(walled)[region].mean() == pytest.approx(luminance(plain)[region].mean(), rel=1e-3)
    assert luminance(walled).mean() == pytest.approx(luminance(plain).mean(), rel=1e-3)


def test_camera_densities_are_zero_out_of_the_clip_range():
    """Eq. 32's camera density is 0 where the camera's rays do not reach,
    and the connection's importance with it; in the range it is
    1 / (film area cos^3) per unit solid angle times |cos| / distance^2."""
    import drjit as dr

    from lathe_shape.plugin.caustic_paths import PinholeCamera

    sensor = scene({"near_clip": 2.0, "far_clip": 6.0}).sensors()[0]
    camera = PinholeCamera(sensor)
    assert camera.film_area == pytest.approx((2.0 * math.tan(math.radians(22.5))) ** 2, rel=1e-5)
    forward = np.array(camera.forward)
    depths = [1.0, 3.0, 5.0, 7.0]
    points = CAMERA[None, :] + np.array(depths)[:, None] * forward[None, :]
    p = mi.Point3f(*(points[:, axis].tolist() for axis in range(3)))
    density = np.array(camera.density(p, mi.Normal3f(0.0, 0.0, 1.0)))
    expected = abs(forward[2]) / (camera.film_area * np.array(depths) ** 2)
    np.testing.assert_allclose(density, [0.0, expected[1], expected[2], 0.0], rtol=1e-5)
    it = dr.zeros(mi.Interaction3f, len(depths))
    it.p = p
    _, importance = camera.connect(sensor, it, mi.Bool(True))
    np.testing.assert_allclose(np.array(importance)[0],
                               [0.0, 1.0 / (camera.film_area * 9.0), 1.0 / (camera.film_area * 25.0), 0.0],
                               rtol=1e-5)


# ---------------------------------------------------------------- principal point offset

@pytest.mark.parametrize("light", ["point", "area"])
def test_principal_point_offset(light):
    """A camera with ``principal_point_offset`` (0.125, 0.5) aimed 2 above
    the ball, whose caustic lies below its unshifted film (0.4% of it on
    that film) and on the shifted one, renders as the crop of a camera with
    a film twice as wide and high that shows the same pixels (the same
    samples: equal but for one pixel of the path tracer's that one ulp
    decides). Mitsuba 3.9.1's own importance is 0 off the unshifted film:
    before, 0.4 of the point light's caustic of 115 was left, and the
    caustic region read 0.036 and 0.038 instead of 0.84 and 1.0; with the
    area light the weights of eq. 32 read the film's area too."""
    aim = T().look_at(origin=CAMERA.tolist(), target=(TARGET + [0.0, 0.0, 2.0]).tolist(), up=[0, 0, 1])
    shifted = scene({"to_world": aim, "principal_point_offset_x": 0.125, "principal_point_offset_y": 0.5},
                    light=light)
    # (B's pixel (x, y) is the wide film's (x + 24 + 48 * 0.125, y + 24 + 48 * 0.5))
    cropped = scene({"to_world": aim, "fov": WIDE_FOV}, light=light,
                    film={"width": 2 * RES, "height": 2 * RES, "crop_offset_x": 30, "crop_offset_y": 48,
                          "crop_width": RES, "crop_height": RES})
    reference = caustic(cropped)
    assert reference.sum() > 100.0
    assert np.abs(caustic(shifted) - reference).sum() < 1e-4 * reference.sum()  # (measured: 4e-5)
    image, expected = luminance(render(shifted, 16, seed=1)), luminance(render(cropped, 16, seed=1))
    region = reference > 0.2 * expected
    assert region.sum() >= 20
    assert (np.abs(image - expected) > 1e-4 * (1.0 + expected)).sum() <= 3


# ---------------------------------------------------------------- directional and environment lights

@pytest.mark.parametrize("light", ["directional", "environment"])
def test_a_far_object_leaves_the_caustic_as_it_is(light):
    """Directional and environment particles start just outside the sphere
    around the lathes: a black speck 10^6 away (which no ray meets) leaves
    their caustic as it is (the same particles: 1e-7 apart). They started
    twice the scene's size away before: the float32 start, 0.06 off its
    line, smeared the caustic (0.7 and 0.3 of it moved at 10^5, 0.8 and
    0.77 at 10^7)."""
    sky = np.full((16, 32, 3), 0.05, dtype=np.float32)
    sky[2:4, 14:16] = 400.0  # a sun high up behind the ball
    lights = {"directional": SUN, "environment": {"env": {"type": "envmap", "bitmap": mi.Bitmap(sky)}}}
    speck = {"speck": {"type": "sphere", "center": [1e6, 0.0, 0.0], "radius": 1.0, "bsdf": BLACK}}
    near = caustic(scene(light="none", sky=False, extra=lights[light]))
    assert near.sum() > 100.0
    far = caustic(scene(light="none", sky=False, extra={**lights[light], **speck}))
    assert np.abs(far - near).sum() < 1e-4 * near.sum()


def test_directional_particles_cross_what_lies_beyond_their_start():
    """A particle that starts near the lathes must still meet what lies
    between that start and the light: a ``thindielectric`` skylight 2.8
    above the ball on the sun's line lets through T' = (1 - R) / (1 + R) of
    the light (Fresnel R at the sun's incidence, its internal reflections
    summed), so the caustic under the ball is T' (0.922) of the one without
    it. (Killing the particles whose way back to the light is blocked
    would leave none; they start from far back there, as before.) Three
    seeds read 0.918-0.923: 0.01 is 4 standard errors."""
    up = -np.array(SUN["sun"]["direction"])
    up /= np.linalg.norm(up)
    centre = np.array([0.0, 0.0, 1.2]) + up * (2.8 / up[2])
    skylight = {"skylight": {"type": "rectangle", "to_world": T().translate(centre.tolist()).scale(2.0),
                             "bsdf": {"type": "thindielectric", "int_ior": 1.5}}}
    reflectance = float(mi.fresnel(mi.Float(float(up[2])), mi.Float(1.5))[0][0])
    transmitted = (1.0 - reflectance) / (1.0 + reflectance)
    open_sky = caustic(scene(light="none", sky=False, extra=SUN))
    region = open_sky > 0.05 * open_sky.max()
    assert region.sum() >= 8
    covered = caustic(scene(light="none", sky=False, extra={**SUN, **skylight}))
    assert covered[region].sum() / open_sky[region].sum() == pytest.approx(transmitted, abs=0.01)


# ---------------------------------------------------------------- films

@pytest.mark.parametrize("pixel_format", ["xyz", "xyza"])
@pytest.mark.parametrize("kind", ["lathe_path", "lathe_volpath"])
def test_xyz_film_gets_the_caustic_in_xyz(pixel_format, kind):
    """An ``xyz`` film develops its RGB samples with Mitsuba's
    ``srgb_to_xyz``: the caustic goes into X, Y and Z alike (the same samples
    as an RGB film's, converted), and the film holds what the render
    returns. Before, X got the caustic's luminance, Y and Z nothing, and the
    film none of it."""
    rgb = render(scene(), 16, seed=1, kind=kind)
    xyz_scene = scene(film={"pixel_format": pixel_format})
    xyz = render(xyz_scene, 16, seed=1, kind=kind)
    assert xyz.shape == (RES, RES, len(pixel_format))
    to_xyz = np.stack([np.array(mi.srgb_to_xyz(mi.Color3f(*unit)), dtype=np.float64).ravel()
                       for unit in np.eye(3).tolist()], axis=1)
    np.testing.assert_allclose(xyz[..., :3], rgb[..., :3] @ to_xyz.T, rtol=1e-4, atol=1e-6)
    film = np.array(xyz_scene.sensors()[0].film().bitmap(), dtype=np.float64)
    np.testing.assert_allclose(film, xyz, rtol=1e-5, atol=1e-6)
    # (the caustic is on: without it, X, Y and Z are lower)
    plain = render(xyz_scene, 16, seed=1, kind=kind, caustics=False)
    assert xyz[..., 1].mean() > 1.05 * plain[..., 1].mean()


def test_srgb_to_xyz_matrix_is_mitsubas():
    from lathe_shape.plugin.caustic_render import srgb_to_xyz_matrix

    np.testing.assert_allclose(srgb_to_xyz_matrix()[1], [0.212671, 0.715160, 0.072169], rtol=1e-5)


# ---------------------------------------------------------------- particle count

def test_particle_limit_is_the_cli_sample_limit():
    from lathe_shape.cli.budget import MAX_SAMPLES
    from lathe_shape.plugin.caustic_render import MAX_PARTICLES, CausticSettings, check_particle_count

    assert MAX_PARTICLES == MAX_SAMPLES == 2**32 - 2**24
    settings = CausticSettings(True, 1000.0, 0.3, 8, "lathe_volpath")
    assert check_particle_count(settings, 16, 512, 512) == 1000 * 16 * 512 * 512  # (4.19e9: fits)
    with pytest.raises(ValueError) as error:
        check_particle_count(settings, 17, 512, 512)
    assert str(error.value) == (
        "lathe_volpath: parameter 'caustic_paths' = 1000 particles per camera sample at 17 spp on a 512x512 "
        "film is 4456448000 light particles, more than the 4278190080 one render may trace: use at most "
        "caustic_paths = 960, fewer spp, or average renders with different seeds")


@pytest.mark.parametrize("kind", ["lathe_path", "lathe_volpath"])
def test_render_refuses_too_many_particles(kind, monkeypatch):
    """A render whose particles would exceed the limit stops before it
    traces anything (1e9 particles ran for hours): here under a limit
    lowered to 1000, 2304 particles."""
    import lathe_shape.plugin.caustic_render as caustic_render

    monkeypatch.setattr(caustic_render, "MAX_PARTICLES", 1000)
    from lathe_shape.cli.common import root_message

    with pytest.raises(RuntimeError) as error:
        render(scene(), 1, kind=kind, caustic_paths=1.0)
    # (mi.render wraps the integrator's error: the message is its cause's)
    assert root_message(error.value).startswith(
        f"{kind}: parameter 'caustic_paths' = 1 particles per camera sample at 1 spp on a 48x48 film is 2304 "
        "light particles, more than the 1000 one render may trace: use at most caustic_paths = 0.434028")
    # (within it, the render runs)
    monkeypatch.setattr(caustic_render, "MAX_PARTICLES", 2304)
    assert np.isfinite(render(scene(), 1, kind=kind, caustic_paths=1.0)).all()
