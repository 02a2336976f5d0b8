"""The caustic of a glass ball lens under a point light (and a spot light)
against its closed form, computed here in float64 NumPy from Snell's law and
the Fresnel equations, independently of the package (``lathe_path``'s
``caustics``, eqs. 32-36).

A glass ball (IOR 1.5 in vacuum, radius 1) hangs 3 above a diffuse floor
(albedo 0.8) with a point light 6 above its centre, on the axis. Path
tracing cannot reach a point light through glass, so the light that the
ball reflects (R) or refracts (TT) onto the floor is the light tracer's
alone. With ``max_depth`` 4 the light tracer's chains are cut to at most
two vertices (m + k <= max_depth - 2): the image holds the floor's direct
light, R and TT, and one path-traced term more, the floor's own light
reflected off the ball back to it (camera, floor, ball, floor, light; at
most 0.6% of the shadow's caustic), which plain path tracing
(``caustics=False``) renders alone. The closed form traces R and TT for
400,000 directions from the light, each carrying the power of its solid
angle times its Fresnel factors, and bins where they land into rings on the
floor: irradiance E(rho), the floor's radiance albedo E / pi.
"""

from __future__ import annotations

import mitsuba as mi
import numpy as np
import pytest

IOR, RADIUS, CENTRE_Z, LIGHT_Z, INTENSITY, ALBEDO = 1.5, 1.0, 3.0, 9.0, 50.0, 0.8
#: The ball's shadow on the floor ends at radius LIGHT_Z tan(asin(1 / 6)) =
#: 1.52; pixels that see radii from SHADOW_EDGE[0] to SHADOW_EDGE[1] are left
#: out (the ball is a 128-segment polyline, not a sphere).
SHADOW_EDGE = (1.45, 1.6)


def fresnel(cos_incident: np.ndarray, eta: float) -> tuple[np.ndarray, np.ndarray]:
    """Unpolarised Fresnel reflectance and the refracted cosine, for the
    incident cosine ``cos_incident`` > 0 and ``eta`` = n_t / n_i."""
    sin_t2 = (1.0 - cos_incident**2) / eta**2
    cos_t = np.sqrt(np.maximum(1.0 - sin_t2, 0.0))
    r_s = (cos_incident - eta * cos_t) / (cos_incident + eta * cos_t)
    r_p = (eta * cos_incident - cos_t) / (eta * cos_incident + cos_t)
    return np.where(sin_t2 >= 1.0, 1.0, 0.5 * (r_s**2 + r_p**2)), cos_t


def circle_hit(origin: np.ndarray, direction: np.ndarray, far: bool) -> np.ndarray:
    """Where the rays (x, z) meet the ball's meridian circle: the near or the
    far root."""
    to_origin = origin - [0.0, CENTRE_Z]
    half_b = np.sum(to_origin * direction, -1)
    root = np.sqrt(np.maximum(half_b**2 - np.sum(to_origin**2, -1) + RADIUS**2, 0.0))
    return origin + (-half_b + (root if far else -root))[:, None] * direction


def floor_irradiance(ray_count: int = 400_000, ring_width: float = 0.004, max_radius: float = 4.0,
                     sigma_t: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(ring centres, irradiance) on the floor of the R and TT paths; TT
    attenuated by ``exp(-sigma_t * chord)`` in a ball that absorbs."""
    cone = np.arcsin(RADIUS / (LIGHT_Z - CENTRE_Z))  # the directions that meet the ball
    cos = np.linspace(1.0, np.cos(cone), ray_count + 1)
    cos = 0.5 * (cos[1:] + cos[:-1])  # equal solid angles
    power = INTENSITY * 2.0 * np.pi * (1.0 - np.cos(cone)) / ray_count
    direction = np.stack([np.sqrt(1.0 - cos**2), -cos], -1)
    p1 = circle_hit(np.tile([0.0, LIGHT_Z], (ray_count, 1)), direction, far=False)
    n1 = (p1 - [0.0, CENTRE_Z]) / RADIUS
    cos_1 = -np.sum(direction * n1, -1)
    f1, cos_t1 = fresnel(cos_1, IOR)
    reflected = direction + 2.0 * cos_1[:, None] * n1
    inside = direction / IOR + (cos_1 / IOR - cos_t1)[:, None] * n1
    p2 = circle_hit(p1, inside, far=True)
    n2 = (p2 - [0.0, CENTRE_Z]) / RADIUS  # facing out: the ray meets it from inside
    cos_2 = np.sum(inside * n2, -1)
    f2, cos_t2 = fresnel(cos_2, 1.0 / IOR)
    out = inside * IOR + (cos_t2 - cos_2 * IOR)[:, None] * n2
    absorbed = np.exp(-sigma_t * np.linalg.norm(p2 - p1, axis=-1))
    edges = np.arange(0.0, max_radius + ring_width, ring_width)
    landed = np.zeros(len(edges) - 1)
    for start, leaving, share in ((p1, reflected, f1), (p2, out, (1.0 - f1) * (1.0 - f2) * absorbed)):
        down = leaving[:, 1] < -1e-9  # (the others never reach the floor)
        distance = -start[:, 1] / np.where(down, leaving[:, 1], -1.0)
        rho = np.abs(start[:, 0] + distance * leaving[:, 0])
        landed += np.histogram(rho[down], edges, weights=power * share[down])[0]
    return 0.5 * (edges[1:] + edges[:-1]), landed / (np.pi * (edges[1:]**2 - edges[:-1]**2))


def direct_irradiance(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The point light's irradiance on the floor at (x, y), 0 in the ball's
    shadow."""
    rho = np.hypot(x, y)
    start = np.stack([rho, np.zeros_like(rho)], -1)
    segment = np.array([0.0, LIGHT_Z]) - start
    nearest = np.clip(np.sum(([0.0, CENTRE_Z] - start) * segment, -1) / np.sum(segment**2, -1), 0.0, 1.0)
    clear = np.linalg.norm(start + nearest[:, None] * segment - [0.0, CENTRE_Z], axis=-1) > RADIUS
    return np.where(clear, INTENSITY * LIGHT_Z / (rho**2 + LIGHT_Z**2) ** 1.5, 0.0)


def ball_lens_scene(resolution: int, light: str = "point", sigma_t: tuple | None = None,
                    pane: dict | None = None) -> mi.Scene:
    """The ball over the floor, lit by a point light or by a spot light
    pointing down whose beam (20 degrees, falling off to 25) holds the ball
    and the floor out to radius 3: the same light there. With ``sigma_t``
    (RGB) the ball is filled with a medium that absorbs (albedo 0); ``pane``:
    one shape more (a pane in front of the camera)."""
    ball = ", ".join(f"{np.sin(t):.6f} {-np.cos(t):.6f}" for t in np.linspace(0.0, np.pi, 129))
    if light == "point":
        emitter = {"type": "point", "position": [0, 0, LIGHT_Z]}
    else:
        emitter = {"type": "spot", "beam_width": 20.0, "cutoff_angle": 25.0,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, LIGHT_Z], target=[0, 0, 0],
                                                              up=[0, 1, 0])}
    ball = {"type": "lathe", "profile": ball,
            "bsdf": {"type": "dielectric", "int_ior": IOR, "ext_ior": 1.0},
            "to_world": mi.ScalarTransform4f().translate([0, 0, CENTRE_Z])}
    if sigma_t is not None:
        ball["interior"] = {"type": "homogeneous", "albedo": 0.0,
                            "sigma_t": {"type": "rgb", "value": list(sigma_t)}}
    return mi.load_dict({
        "type": "scene",
        "sensor": {"type": "perspective", "fov": 30,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, -9, 5], target=[0, 0, 0],
                                                              up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                            "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                   "sampler": {"type": "independent"}},
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale([20, 20, 1]),
                  "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": [ALBEDO] * 3}}},
        "ball": ball,
        "light": {**emitter, "intensity": {"type": "rgb", "value": [INTENSITY] * 3}},
        **({"pane": pane} if pane else {}),
    })


def closed_form_image(scene: mi.Scene, resolution: int, subsamples: int = 4, sigma_t: tuple = (0.0,)
                      ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per pixel (``subsamples`` squared camera rays each): the closed
    form's radiance of the light tracer's paths (R, TT; the mean over the
    colour channels' ``sigma_t``) and of the direct light, whether a ray
    meets the ball, and the floor radii seen (mean, least, greatest)."""
    side = resolution * subsamples
    rows, columns = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    position = mi.Point2f(mi.Float(((columns + 0.5) / side).ravel()), mi.Float(((rows + 0.5) / side).ravel()))
    ray, _ = scene.sensors()[0].sample_ray(0.0, 0.5, position, mi.Point2f(0.5))
    direction = np.array(ray.d, dtype=np.float64).reshape(3, -1).T
    origin = np.broadcast_to(np.array(ray.o, dtype=np.float64).reshape(3, -1).T, direction.shape)
    distance = -origin[:, 2] / direction[:, 2]
    x, y = origin[:, 0] + distance * direction[:, 0], origin[:, 1] + distance * direction[:, 1]
    to_origin = origin - [0.0, 0.0, CENTRE_Z]
    half_b = np.sum(to_origin * direction, -1)
    discriminant = half_b**2 - np.sum(to_origin**2, -1) + RADIUS**2
    meets_ball = (discriminant > 0.0) & (-half_b - np.sqrt(np.maximum(discriminant, 0.0)) > 0.0)
    rho = np.hypot(x, y)
    traced = np.zeros_like(rho)
    for sigma in sigma_t:
        rings, irradiance = floor_irradiance(sigma_t=sigma)
        traced += ALBEDO / np.pi * np.interp(rho, rings, irradiance, right=0.0) / len(sigma_t)
    direct = ALBEDO / np.pi * direct_irradiance(x, y)

    def per_pixel(values: np.ndarray, reduce) -> np.ndarray:
        """``reduce`` (np.mean, np.any, ...) over each pixel's rays."""
        return reduce(values.reshape(resolution, subsamples, resolution, subsamples), axis=(1, 3))

    return (per_pixel(traced, np.mean), per_pixel(direct, np.mean), per_pixel(meets_ball, np.any),
            per_pixel(rho, np.mean), per_pixel(rho, np.min), per_pixel(rho, np.max))


#: The absorbing ball's extinction per unit length (RGB): its chords (up to
#: 2) keep 82%, 37% and 14% of the light at most.
ABSORBING = (0.1, 0.5, 1.0)


@pytest.mark.parametrize("integrator, light, sigma_t", [
    ("lathe_path", "point", None),
    ("lathe_path", "spot", None),
    ("lathe_volpath", "point", ABSORBING),
])
def test_ball_lens_caustic_matches_its_closed_form(integrator, light, sigma_t):
    """Rings 0.2 wide on the floor seen directly (not through the ball): in
    the ball's shadow (radius 0.2-1.4), the light tracer's part of the
    render (the render less plain path tracing's, with the same samples)
    within 2% of the closed form in each ring and 0.7% over all of them;
    outside it (1.7-2.7: direct light and the light the ball reflects or
    refracts there), the render within 0.5% (its path-traced term adds
    0.1% there). Measured at 64x64, 64 spp, 16 particles per camera
    sample: within 0.44% and 0.08%. The same for a spot light whose beam
    holds it all, and for a coloured ball filled with a medium that absorbs
    (``lathe_volpath``: the particles carry its transmittance along their
    chords; measured: within 0.42% per ring, 0.02% over the shadow and 0.2%
    outside it)."""
    resolution = 64
    scene = ball_lens_scene(resolution, light, sigma_t)

    def render(**params) -> np.ndarray:
        plugin = mi.load_dict({"type": integrator, "max_depth": 4, **params})
        image = mi.render(scene, integrator=plugin, spp=64, seed=1)
        return np.array(image, dtype=np.float64)[..., :3].mean(-1)

    image, plain_image = render(caustic_paths=16.0), render(caustics=False)
    traced, direct, through_ball, rho, rho_low, rho_high = closed_form_image(
        scene, resolution, sigma_t=sigma_t or (0.0,))
    seen = ~through_ball & ((rho_high < SHADOW_EDGE[0]) | (rho_low > SHADOW_EDGE[1]))
    shadow = np.zeros_like(seen)
    for low in (*np.arange(0.2, 1.3, 0.2), *np.arange(1.7, 2.6, 0.2)):
        ring = seen & (rho >= low) & (rho < low + 0.2)
        assert ring.sum() >= 20, f"radius {low:.1f}: the ring must be on the film"
        if low < SHADOW_EDGE[0]:
            light_traced = image[ring] - plain_image[ring]
            assert light_traced.mean() == pytest.approx(traced[ring].mean(), rel=0.02), f"radius {low:.1f}"
            shadow |= ring
        else:
            expected = traced[ring] + direct[ring]
            assert image[ring].mean() == pytest.approx(expected.mean(), rel=0.005), f"radius {low:.1f}"
    assert (image - plain_image)[shadow].mean() == pytest.approx(traced[shadow].mean(), rel=0.007)
    assert direct[shadow].max() == 0.0 and plain_image[shadow].mean() < 0.01 * traced[shadow].mean()


def test_ball_lens_caustic_through_a_tinted_pane():
    """The ball lens seen through an index-matched pane 0.1 thick that absorbs
    (sigma_t 1, 0.5 and 0.25 per channel) and fills the view: every particle
    in the ball's shadow reaches the camera through the solver's chain of two
    vertices (eqs. 37-40), whose throughput must hold the pane's
    transmittance along it (eq. 44, ``lathe_volpath``). The light tracer's
    part of the render against the closed form times exp(-sigma_t 0.1 /
    cos) of each camera ray, per channel and ring, within 2% (measured:
    0.45%; left out, the transmittance is 2.5-10% per channel)."""
    resolution, subsamples, sigma_t = 64, 4, (1.0, 0.5, 0.25)
    camera = np.array([0.0, -9.0, 5.0])
    axis = -camera / np.linalg.norm(camera)  # the camera looks at the origin
    facing = mi.ScalarTransform4f().look_at(origin=(camera + 1.5 * axis).tolist(), target=camera.tolist(),
                                            up=[0, 0, 1])
    scene = ball_lens_scene(resolution, pane={
        "type": "lathe", "profile": "0 -0.05, 1.5 -0.05, 1.5 0.05, 0 0.05", "to_world": facing,
        "bsdf": {"type": "dielectric", "int_ior": 1.0, "ext_ior": 1.0},
        "interior": {"type": "homogeneous", "albedo": 0.0, "scale": 4.0,
                     "sigma_t": {"type": "rgb", "value": [value / 4.0 for value in sigma_t]}}})

    def render(**params) -> np.ndarray:
        # (max_depth 6: the chains through the pane, m = 2, with R and TT, k <= 2)
        plugin = mi.load_dict({"type": "lathe_volpath", "max_depth": 6, **params})
        return np.array(mi.render(scene, integrator=plugin, spp=64, seed=1), dtype=np.float64)[..., :3]

    light_traced = render(caustic_paths=16.0, caustic_camera_chains=1.0) - render(caustics=False)
    traced, _, through_ball, rho, rho_low, rho_high = closed_form_image(scene, resolution, subsamples)
    side = resolution * subsamples
    rows, columns = np.meshgrid(np.arange(side), np.arange(side), indexing="ij")
    position = mi.Point2f(mi.Float(((columns + 0.5) / side).ravel()), mi.Float(((rows + 0.5) / side).ravel()))
    ray, _ = scene.sensors()[0].sample_ray(0.0, 0.5, position, mi.Point2f(0.5))
    cos = np.abs(np.array(ray.d, dtype=np.float64).reshape(3, -1).T @ axis)
    seen = ~through_ball & (rho_high < SHADOW_EDGE[0])
    for channel, sigma in enumerate(sigma_t):
        pane = np.exp(-sigma * 0.1 / cos).reshape(resolution, subsamples, resolution, subsamples)
        expected = traced * pane.mean(axis=(1, 3))
        for low in np.arange(0.2, 1.3, 0.2):
            ring = seen & (rho >= low) & (rho < low + 0.2)
            assert ring.sum() >= 20
            assert light_traced[..., channel][ring].mean() == pytest.approx(expected[ring].mean(), rel=0.02)
