"""Differentiable lathes: the ``points`` parameter and ``lathe_prb``
gradients against central finite differences of the exact render."""

from __future__ import annotations

import re

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from lathe_shape.plugin.shape import scene_lathes
from lathe_shape.profiles import ProfileError
from lathe_shape.tools.diff_scenes import DEFAULT_PROFILE, lathe_scene
from lathe_shape.tools.gradients import (
    check_gradient,
    finite_difference,
    forward_gradient,
    pixel_classes,
    points_key,
)

#: Flat indices into DEFAULT_PROFILE's points "0 0, 0.6 0, 0.7 0.35, 0.72
#: 0.7, 0.6 1.0, 0.4 1.2, 0 1.2": r of a smooth vertex on the bowl, r of the
#: creased rim of the top cap, z of the top point on the axis.
CASES = {"bowl": 6, "crease": 10, "axis": 13}

#: The same points as B-spline control points: the bottom corner (where the
#: curve turns most sharply) stands in for the crease.
BSPLINE_CASES = {"bowl": 6, "corner": 2, "axis": 13}


def _points_params(scene):
    params = mi.traverse(scene)
    return params, points_key(params, scene_lathes(scene)[0])


def _summed_points_gradient(scene, spp: int = 4, seed: int = 1) -> np.ndarray:
    """Reverse mode: the gradient of the image's sum with respect to the
    lathe's points (flat, user order)."""
    params, key = _points_params(scene)
    value = params[key]
    dr.enable_grad(value)
    params.update()
    image = mi.render(scene, params, spp=spp, seed=seed)
    dr.backward(dr.sum(image, axis=None))
    return np.array(dr.grad(value))


# -- the parameter -----------------------------------------------------------

def test_points_exposed_in_user_order():
    scene = lathe_scene(resolution=8)
    params, key = _points_params(scene)
    assert key == "lathe.points"
    given = np.array([[float(v) for v in p.split()] for p in DEFAULT_PROFILE.split(",")])
    # The canonical (clockwise) profile is the reverse; the parameter keeps the user's order
    np.testing.assert_allclose(np.array(params[key]).reshape(-1, 2), given, atol=1e-7)


def test_update_rebuilds_kernel_and_mesh():
    scene = lathe_scene(resolution=8)
    params, key = _points_params(scene)
    values = np.array(params[key])
    values[6] = 1.5  # the bowl's widest vertex moves out
    params[key] = mi.Float(values)
    params.update()
    lathe = scene_lathes(scene)[0]
    assert lathe.profile.bounds()[0] == pytest.approx(1.5)
    assert scene.bbox().max.x == pytest.approx(1.5, rel=1e-3)
    ray = mi.Ray3f(mi.Point3f(3.0, 0.0, 0.7), mi.Vector3f(-1.0, 0.0, 0.0))
    assert lathe.ray_intersect_exact(ray).t[0] == pytest.approx(1.5, rel=1e-5)
    assert scene.ray_intersect(ray).t[0] == pytest.approx(1.5, rel=1e-2)  # the reference mesh


@pytest.mark.parametrize("bad, message", [
    (-0.5, "lathe 'lathe': parameter 'points', point 4: negative radius r = -0.5"),
    (float("nan"), "non-finite"), (0.0, "intersects itself")])
def test_invalid_update_keeps_previous_profile(bad, message):
    scene = lathe_scene(resolution=8)
    params, key = _points_params(scene)
    before = np.array(params[key])
    values = before.copy()
    if message == "intersects itself":
        values[8:10] = [1.0, 0.2]  # (0.6, 1.0) dragged below the bowl
    else:
        values[6] = bad
    params[key] = mi.Float(values)
    with pytest.raises(ProfileError, match=re.escape(message)):
        params.update()
    np.testing.assert_array_equal(np.array(params[key]), before)
    assert scene_lathes(scene)[0].profile.bounds()[0] == pytest.approx(0.72)


def test_points_from_xml(tmp_path):
    xml = tmp_path / "scene.xml"
    xml.write_text(
        '<scene version="3.0.0"><shape type="lathe" id="glass">'
        '<string name="profile" value="0 0, 1 0, 1 1, 0 1"/></shape></scene>'
    )
    scene = mi.load_file(str(xml))
    params = mi.traverse(scene)
    np.testing.assert_allclose(np.array(params["glass.points"]), [0, 0, 1, 0, 1, 1, 0, 1])
    params["glass.points"] = mi.Float([0, 0, 2, 0, 2, 1, 0, 1])
    params.update()
    assert scene.bbox().max.x == pytest.approx(2.0, rel=1e-3)


# -- gradients ----------------------------------------------------------------

@pytest.mark.slow
def test_forward_equals_backward():
    scene = lathe_scene(resolution=24)
    params, key = _points_params(scene)
    forward = [forward_gradient(scene, key, i, spp=4, seed=5).sum() for i in (6, 13)]
    value = params[key]
    dr.enable_grad(value)
    params.update()
    film = scene.sensors()[0].film()
    weights = mi.TensorXf(np.ones((film.size()[1], film.size()[0], 3), dtype=np.float32))
    scene.integrator().render_backward(scene, params, weights, seed=5, spp=4)
    backward = np.array(dr.grad(value))
    np.testing.assert_allclose(backward[[6, 13]], forward, rtol=1e-3, atol=1e-4)


@pytest.mark.parametrize("kind", ["polyline", "bspline"])
def test_adam_keeps_the_axis_points_on_the_axis(kind):
    """A user's optimisation loop (mi.ad.Adam, params.update(opt)): the
    axis points' r had a derivative (-1e-18 on the polyline, rounding;
    0.001-0.005 on the B-spline), Adam's first step moved them off the
    axis, and the update refused the open profile. They are held: r is 0
    with a zero derivative, and every other coordinate moves."""
    scene = lathe_scene(kind=kind, resolution=24)
    params, key = _points_params(scene)
    target = mi.render(scene, params, spp=4, seed=0)
    axis = np.flatnonzero(np.array(params[key])[0::2] == 0.0) * 2  # flat indices of the axis points' r
    assert len(axis) == 2
    optimizer = mi.ad.Adam(lr=0.01)
    start = np.array(params[key])
    optimizer[key] = mi.Float(start * np.where(np.arange(len(start)) % 2 == 0, 1.05, 1.0).astype(np.float32))
    params.update(optimizer)
    for step in range(3):
        image = mi.render(scene, params, spp=4, seed=step + 1)
        dr.backward(dr.mean(dr.square(image - target)))
        grad = np.array(dr.grad(optimizer[key]))
        assert np.all(grad[axis] == 0.0) and np.count_nonzero(grad) >= 4
        optimizer.step()
        params.update(optimizer)
    points = np.array(params[key])
    assert np.all(points[axis] == 0.0) and np.abs(points - start).max() > 0.005


def test_invisible_lathe_has_zero_gradient():
    scene = lathe_scene(resolution=16, offset=(0.0, 0.0, 40.0))  # far above the view
    assert np.all(_summed_points_gradient(scene) == 0.0)


#: Tolerances on silhouette pixels: the outline term (edge sampling of the
#: exact silhouette) against finite differences with enough samples for the
#: pixels' coverage to vary smoothly (h = 0.01, 256 spp; the FD's own noise
#: there is 5-10%). Measured relative errors (seed 3): polyline bowl 3%,
#: crease 1%, axis 0.5%; B-spline bowl 8%, corner 16%, axis 4%. The
#: B-spline corner exceeds 10%: the documented bias
#: (docs/differentiable.md).
SILHOUETTE_TOLERANCE = {("polyline", "bowl"): 0.1, ("polyline", "crease"): 0.1, ("polyline", "axis"): 0.1,
                        ("bspline", "bowl"): 0.1, ("bspline", "corner"): 0.2, ("bspline", "axis"): 0.1}


@pytest.mark.parametrize("kind, case", sorted(SILHOUETTE_TOLERANCE))
@pytest.mark.slow
def test_gradient_matches_finite_differences(kind, case):
    """Interior pixels within 10% (measured: below 0.5%), silhouette pixels
    within SILHOUETTE_TOLERANCE."""
    scene = lathe_scene(kind=kind, resolution=24)
    index = (CASES if kind == "polyline" else BSPLINE_CASES)[case]
    check = check_gradient(scene, scene_lathes(scene)[0], index, h=1e-2, spp=256, seed=3)
    assert abs(check.fd_interior) > 0.05  # the FD stands far above its float32 noise
    assert check.interior_error < 0.1, check
    error = abs(check.ad_silhouette - check.fd_silhouette) / abs(check.fd_silhouette)
    assert error < SILHOUETTE_TOLERANCE[kind, case], check


def test_silhouette_term_is_needed():
    """Without the outline term the silhouette pixels lose most of the
    gradient (the bias that the term removes)."""
    scene = lathe_scene(resolution=24)
    scene.integrator().silhouette = False
    check = check_gradient(scene, scene_lathes(scene)[0], CASES["bowl"], h=1e-2, spp=256, seed=3)
    assert abs(check.fd_silhouette) > 0.5 * abs(check.fd_total)
    assert abs(check.ad_silhouette - check.fd_silhouette) > 0.5 * abs(check.fd_silhouette)


def test_curve_kinds_without_point_gradients():
    # A sor lathe renders with lathe_prb (its r^2 cubic in z has no attached
    # hit); asking for its points' gradient is
    # refused with the kinds that support it.
    profile = "0.5 -0.1, 0.5 0, 0.6 0.4, 0.4 0.8, 0.3 1.2, 0.3 1.3"
    scene = lathe_scene(profile, kind="sor", resolution=8)
    image = mi.render(scene, spp=2)
    assert np.isfinite(np.array(image)).all() and np.array(image).mean() > 0.0
    params, key = _points_params(scene)
    dr.enable_grad(params[key])
    params.update()
    with pytest.raises(Exception) as error:  # noqa: PT011 (Dr.Jit wraps it; the cause is checked)
        mi.render(scene, params, spp=2)
    causes = [error.value]
    while causes[-1].__cause__ is not None:
        causes.append(causes[-1].__cause__)
    expected = ("'points' are available for the kinds polyline, bspline, bezier, catmull_rom and quadratic, "
                "not 'sor'")
    assert any(expected in str(e) for e in causes), causes


# -- POV-Ray's cubic kinds: points mapped to B-spline controls (eq. 18) ------

#: Control points of each kind (bezier: the vase of scenes/pov_samples;
#: catmull_rom: its goblet, hollow; quadratic: a cup).
CURVE_KIND_POINTS = {
    "bezier": [(0, 0), (2.2, 0), (2.6, 0.5), (2.6, 2.5), (2.6, 2.5), (2.6, 5.5), (0.8, 6.2), (1.1, 8.5),
               (1.1, 8.5), (1.2, 9), (0.6, 9), (0, 9)],
    "catmull_rom": [(0, -0.2), (0, 0), (2.5, 0.1), (2.4, 0.35), (0.35, 0.6), (0.3, 3.5), (1.5, 4.3),
                    (2.6, 6), (2.8, 8), (2.65, 8.05), (2.45, 6.2), (1.4, 4.7), (0, 4.4), (0, 4.2)],
    "quadratic": [(0.0, -0.3), (0, 0), (0.6, 0), (0.7, 0.35), (0.72, 0.7), (0.6, 1.0), (0.4, 1.2), (0, 1.2)],
}


@pytest.mark.parametrize("reverse", [False, True], ids=["given", "reversed"])
@pytest.mark.parametrize("kind", sorted(CURVE_KIND_POINTS))
def test_curve_kind_points_drive_the_attached_curve(kind, reverse):
    """The attached profile point of a cubic kind (its B-spline controls as
    weighted sums of the user's points) equals the kernel's curve, and its
    derivative with respect to one user coordinate equals a float64 central
    difference of the curve rebuilt from moved points, in either
    orientation of the user's list (a reversed list is turned clockwise)."""
    from lathe_shape.kernels.attached import profile_point
    from lathe_shape.profiles import bspline as bs
    from lathe_shape.surfaces import make_surface

    points = np.array(CURVE_KIND_POINTS[kind], dtype=np.float64)
    if reverse and kind == "quadratic":  # its first point is a tangent control, at the start
        points = np.vstack([[0.0, 1.5], points[:0:-1]])
    elif reverse:
        points = points[::-1]
    lathe = mi.load_dict({"type": "lathe", "kind": kind, "reference": "proxy",
                          "profile": ", ".join(f"{r} {z}" for r, z in points)})
    n_seg = lathe.profile.segment_count
    seg = np.repeat(np.arange(n_seg), 5)
    u = np.tile(np.linspace(0.05, 0.95, 5), n_seg)
    coordinate = 2 * (len(points) // 2) + 1  # z of a middle point
    value = lathe.profile_points
    dr.enable_grad(value)
    r, z = profile_point(value, lathe.profile_index, "bspline", mi.UInt32(seg), mi.Float(u))
    dr.set_grad(value, mi.Float(np.eye(len(value), dtype=np.float32)[coordinate]))
    dr_dz = [np.array(g) for g in dr.forward_to(r, z)]
    expected = bs.evaluate(lathe.profile.segment_controls, seg, u)
    np.testing.assert_allclose(np.array(r), expected[0], atol=2e-6 * 9)
    np.testing.assert_allclose(np.array(z), expected[1], atol=2e-6 * 9)

    def curve(shift):
        moved = points.copy()
        moved.flat[coordinate] += shift
        surface = make_surface(kind, moved, np.zeros(len(moved), dtype=bool), [""] * len(moved), "test")
        return np.array(bs.evaluate(surface.profile.segment_controls, seg, u))

    h = 1e-4
    difference = (curve(h) - curve(-h)) / (2 * h)
    assert np.abs(difference).max() > 0.1  # the point moves the curve
    np.testing.assert_allclose(np.stack(dr_dz), difference, atol=1e-5)


#: Flat indices of the POV-Ray kinds' points on the diffuse vase (the
#: default profile through catmull_rom and bezier controls), with the
#: outline tolerance. Measured (seed 3, 256 spp, h = 0.01): interior within
#: 0.2%; outline 6% (catmull_rom, bowl point r) and 13% (bezier, an inner
#: control r of the bowl's segment), the B-spline outline bias.
CURVE_KIND_CASES = {("catmull_rom", 8): 0.12, ("bezier", 18): 0.2}


def _curve_kind_vase(kind: str) -> np.ndarray:
    from lathe_shape.profiles.spline_kinds import catmull_rom_through

    points = np.array([[float(v) for v in p.split()] for p in DEFAULT_PROFILE.split(",")])
    if kind == "catmull_rom":
        controls = catmull_rom_through(points)
        controls[[0, -1], 0] = 0.0  # tangent controls on the axis
        return controls
    # bezier: each polyline segment a cubic bowed 0.02 outwards
    bow = np.array([0.02, 0.0])
    return np.array([q for a, b in zip(points[:-1], points[1:], strict=True)
                     for q in (a, a + (b - a) / 3 + bow, a + 2 * (b - a) / 3 + bow, b)])


@pytest.mark.parametrize("kind, index", sorted(CURVE_KIND_CASES))
@pytest.mark.slow
def test_curve_kind_gradient_matches_finite_differences(kind, index):
    scene = lathe_scene(_curve_kind_vase(kind), kind=kind, resolution=24)
    check = check_gradient(scene, scene_lathes(scene)[0], index, h=1e-2, spp=256, seed=3)
    assert abs(check.fd_interior) > 0.5
    assert check.interior_error < 0.02, check
    error = abs(check.ad_silhouette - check.fd_silhouette) / abs(check.fd_silhouette)
    assert error < CURVE_KIND_CASES[kind, index], check


@pytest.mark.slow
def test_crease_seen_from_the_front_moves_with_its_vertex():
    """The vase's rim is a crease of the shading normal (side cone against
    top cap); seen from above, its front half is inside the image of the
    lathe, where the radiance jumps across it. Moving the rim vertex moves
    that edge: its pixels (neither interior nor outline pixels) get the
    crease term. Measured (h = 0.01, 256 spp): -23.6 against -23.6 (r),
    -17.2 against -17.5 (z), correlation 0.98-0.99; without the crease
    term -19.0 and -25.2, correlation 0.18-0.34."""
    scene = lathe_scene(resolution=24)
    lathe = scene_lathes(scene)[0]
    key = points_key(mi.traverse(scene), lathe)
    interior, outline = pixel_classes(scene, lathe)
    crease = ~interior & ~outline
    for index in (CASES["crease"], CASES["crease"] + 1):
        ad = forward_gradient(scene, key, index, spp=256, seed=3).sum(axis=2)[crease]
        fd = finite_difference(scene, key, index, 1e-2, spp=256, seed=3).sum(axis=2)[crease]
        assert np.abs(fd).sum() > 10.0
        assert np.corrcoef(ad, fd)[0, 1] > 0.95, index
        assert abs(ad.sum() - fd.sum()) < 0.05 * np.abs(fd).sum(), (index, ad.sum(), fd.sum())


@pytest.mark.parametrize("props, message", [
    ({"grazing_cosine": 1.5}, "lathe_prb: parameter 'grazing_cosine' must be in (0, 1), got 1.5"),
    ({"grazing_cosine": 0.0}, "lathe_prb: parameter 'grazing_cosine' must be in (0, 1), got 0"),
    ({"silhouette_spp": 0}, "lathe_prb: parameter 'silhouette_spp' must be >= 1, got 0"),
    ({"glass_outline_lines": 0}, "lathe_prb: parameter 'glass_outline_lines' must be >= 1, got 0"),
    # Mitsuba's RBIntegrator took any type here (a float max_depth failed only in the render)
    ({"max_depth": 3.0}, "lathe_prb: parameter 'max_depth' must be given as <integer>, got 3.0"),
    ({"max_depth": -3}, "lathe_prb: parameter 'max_depth' must be -1 (infinite) or >= 0, got -3"),
    ({"rr_depth": 2.5}, "lathe_prb: parameter 'rr_depth' must be given as <integer>, got 2.5"),
    ({"rr_depth": 0}, "lathe_prb: parameter 'rr_depth' must be > 0, got 0")])
def test_prb_parameter_errors(props, message):
    with pytest.raises(RuntimeError, match=re.escape(message)):
        mi.load_dict({"type": "lathe_prb", **props})
    assert mi.load_dict({"type": "lathe_prb", "grazing_cosine": 0.1}).grazing_cosine == pytest.approx(0.1)


# -- the differential pass's compacted lanes -------------------------------------

@pytest.mark.parametrize("seed", [0, 7])
def test_compacted_lanes_draw_the_primal_numbers(seed):
    """The differential pass keeps only the camera samples that meet a
    surface; their sampler (lane_sampler) draws, lane for lane, what the
    sensor's independent sampler draws after the camera sample."""
    from lathe_shape.plugin.lane_sampler import camera_draws, lane_sampler

    scene = lathe_scene(resolution=8)
    sensor = scene.sensors()[0]
    sampler = sensor.sampler().clone()
    sampler.set_samples_per_wavefront(4)
    sampler.seed(seed, 8 * 8 * 4)
    for _ in range(camera_draws(sensor)):
        sampler.next_1d()
    expected = np.array([np.array(sampler.next_1d()) for _ in range(5)])
    lanes = np.array([0, 3, 17, 100, 255])
    mine = lane_sampler(sensor, seed, mi.UInt32(lanes))
    drawn = np.array([np.array(mine.next_1d()) for _ in range(5)])
    np.testing.assert_array_equal(drawn, expected[:, lanes])
    assert lane_sampler(mi.load_dict({"type": "perspective", "sampler": {"type": "stratified"}}), seed,
                        mi.UInt32(lanes)) is None


@pytest.mark.slow
def test_other_samplers_still_differentiate():
    """With a sampler other than independent, the compacted lanes draw from
    a sampler of their own (unpaired): forward and backward mode still
    agree, and the gradient agrees with the paired one within the noise."""
    gradients = {}
    for kind in ("independent", "stratified"):
        scene = mi.load_dict({
            "type": "scene", "integrator": {"type": "lathe_prb", "max_depth": 2},
            "lathe": {"type": "lathe", "profile": DEFAULT_PROFILE, "bsdf": {"type": "diffuse"}},
            "light": {"type": "point", "position": [2.0, -2.0, 3.0],
                      "intensity": {"type": "rgb", "value": 20.0}},
            "camera": {"type": "perspective", "fov": 35,
                       "to_world": mi.ScalarTransform4f().look_at([3, 0.5, 2.5], [0, 0, 0.6], [0, 0, 1]),
                       "film": {"type": "hdrfilm", "width": 24, "height": 24, "rfilter": {"type": "box"}},
                       "sampler": {"type": kind, "sample_count": 64}}})
        params, key = _points_params(scene)
        value = params[key]
        dr.enable_grad(value)
        params.update()
        weights = mi.TensorXf(np.ones((24, 24, 3), dtype=np.float32))
        scene.integrator().render_backward(scene, params, weights, seed=5)
        gradients[kind] = np.array(dr.grad(value))
        dr.disable_grad(value)
        forward = forward_gradient(scene, key, 6, spp=64, seed=5).sum()
        np.testing.assert_allclose(gradients[kind][6], forward, rtol=1e-3, atol=1e-4)
    scale = np.abs(gradients["independent"]).max()
    np.testing.assert_allclose(gradients["stratified"], gradients["independent"], atol=0.05 * scale)


def test_environment_seen_directly_keeps_its_gradient():
    """The differential pass drops the camera samples that meet nothing,
    except where they see the environment: its own parameters' gradient
    (here its scale) agrees with Mitsuba's prb on the lathe's mesh (without
    the exception: 277 against 1258)."""
    gradients = {}
    for integrator in ("lathe_prb", "prb"):
        scene = mi.load_dict({
            "type": "scene", "integrator": {"type": integrator, "max_depth": 3},
            "lathe": {"type": "lathe", "profile": DEFAULT_PROFILE, "bsdf": {"type": "diffuse"},
                      "mesh_segments": 256},
            "sky": {"type": "envmap", "bitmap": mi.Bitmap(np.full((16, 32, 3), 0.5, dtype=np.float32))},
            "camera": {"type": "perspective", "fov": 35,
                       "to_world": mi.ScalarTransform4f().look_at([3, 0.5, 2.5], [0, 0, 0.6], [0, 0, 1]),
                       "film": {"type": "hdrfilm", "width": 32, "height": 32, "rfilter": {"type": "box"}}}})
        params = mi.traverse(scene)
        dr.enable_grad(params["sky.scale"])
        params.update()
        image = mi.render(scene, params, spp=64, seed=1)
        dr.backward(dr.sum(image, axis=None))
        gradients[integrator] = float(np.array(dr.grad(params["sky.scale"])).ravel()[0])
    assert gradients["lathe_prb"] == pytest.approx(gradients["prb"], rel=0.02)


def _vase_with(sensor: str) -> mi.Scene:
    camera = mi.ScalarTransform4f().look_at(origin=[0, -3, 1.2], target=[0, 0, 0.5], up=[0, 0, 1])
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "lathe_prb", "max_depth": 4},
        "sensor": {"type": sensor, "to_world": camera,
                   "film": {"type": "hdrfilm", "width": 16, "height": 16}},
        "light": {"type": "point", "position": [2, -2, 3], "intensity": {"type": "rgb", "value": 20}},
        "vase": {"type": "lathe", "profile": "0 0, 0.6 0, 0.7 0.5, 0.4 1, 0 1",
                 "bsdf": {"type": "diffuse", "reflectance": {"type": "rgb", "value": 0.5}}}})


@pytest.mark.parametrize("sensor", ["perspective", "orthographic"])
def test_bsdf_gradient_forward_and_backward(sensor):
    """Forward mode on a BSDF parameter failed ('tried to forward-propagate
    derivatives across edge ... outside of the current dr.isolate_grad()
    scope': the reflectance is read inside the BSDF's method, called as a
    function); an orthographic camera refused every gradient, though the
    outline terms it cannot take belong to the points alone. Forward equals
    backward, and both match a finite difference."""
    scene = _vase_with(sensor)
    params = mi.traverse(scene)
    key = "vase.bsdf.reflectance.value"
    dr.enable_grad(params[key])
    params.update()
    dr.set_grad(params[key], 1.0)
    forward = np.array(scene.integrator().render_forward(scene, params, spp=4, seed=2))[..., :3].sum()
    dr.set_grad(params[key], 0.0)
    weights = mi.TensorXf(np.ones((16, 16, 3), dtype=np.float32))
    scene.integrator().render_backward(scene, params, weights, spp=4, seed=2)
    backward = float(np.sum(dr.grad(params[key])))
    assert forward > 1.0 and abs(forward - backward) <= 1e-3 * abs(forward)
    dr.disable_grad(params[key])
    images = []
    for value in (0.49, 0.51):
        params[key] = mi.Color3f(value)
        params.update()
        images.append(np.array(mi.render(scene, spp=4, seed=2))[..., :3].sum())
    assert abs((images[1] - images[0]) / 0.02 - forward) <= 1e-2 * abs(forward)
    if sensor == "orthographic":  # (the points' gradient still needs a perspective camera)
        dr.enable_grad(params["vase.points"])
        params.update()
        with pytest.raises(Exception, match="need a perspective or thinlens camera"):
            scene.integrator().render_backward(scene, params, weights, spp=1)


def test_adam_moves_a_closing_copy_with_the_first_point():
    """A closed loop written with its first point repeated last: the
    gradient reaches the first copy alone, Adam moved only it, and the next
    update refused the open profile. The copy follows the first point."""
    scene = lathe_scene(profile="0.3 0, 0.6 0, 0.6 0.5, 0.3 0.5, 0.3 0", resolution=16)
    params, key = _points_params(scene)
    optimizer = mi.ad.Adam(lr=0.01)
    optimizer[key] = params[key]
    params.update(optimizer)
    for step in range(3):
        image = mi.render(scene, params, spp=4, seed=step)
        dr.backward(dr.mean(dr.square(image - 0.3)))
        optimizer.step()
        params.update(optimizer)
    given = scene_lathes(scene)[0].surface.given.points
    assert np.array_equal(given[0], given[-1]) and np.abs(given[0] - [0.3, 0.0]).max() > 0.005


@pytest.mark.parametrize("kind", ["polyline", "bspline"])
def test_a_closed_loops_points_on_the_axis_are_free(kind):
    """Only a solid's two ends on the axis are held: a closed loop that
    touches the axis at its first (and repeated last) point moves there."""
    from lathe_shape.plugin.profile_param import profile_index

    scene = lathe_scene(profile="0 0.5, 1 0, 1.2 0.5, 1 1, 0 0.5", kind=kind, resolution=8)
    held = np.array(profile_index(scene_lathes(scene)[0].surface).held)
    assert not held.any()
    solid = lathe_scene(kind=kind, resolution=8)
    assert np.array(profile_index(scene_lathes(solid)[0].surface).held).tolist() == [
        True, False, False, False, False, False, True]


#: A ring (a closed B-spline with its first point repeated last), written
#: clockwise and counter-clockwise from the same first point.
RING_CLOCKWISE = "0.5 0, 0.5 1, 1 1, 1 0, 0.5 0"
RING_COUNTER_CLOCKWISE = "0.5 0, 1 0, 1 1, 0.5 1, 0.5 0"


@pytest.mark.parametrize("profile", [RING_CLOCKWISE, RING_COUNTER_CLOCKWISE], ids=["cw", "ccw"])
def test_closed_bspline_first_point_drives_the_curve_in_either_orientation(profile):
    """The attached curve's derivative with respect to every coordinate of
    a closed B-spline equals a float64 central difference of the curve
    rebuilt from moved points (the first point moves its closing copy with
    it, as an update does), and the copy's derivative is zero. Written
    counter-clockwise (reversed to run clockwise), the index map once kept
    the copy and dropped the first point: the first point's derivative was
    zero and the copy took it, so Adam never moved the first point."""
    from lathe_shape.kernels.attached import profile_point
    from lathe_shape.profiles import bspline as bs

    lathe = mi.load_dict({"type": "lathe", "kind": "bspline", "reference": "proxy", "profile": profile})
    points = np.array([[float(v) for v in p.split()] for p in profile.split(",")])
    n_seg = lathe.profile.segment_count
    seg = np.repeat(np.arange(n_seg), 5)
    u = np.tile(np.linspace(0.05, 0.95, 5), n_seg)

    def curve(coordinate, shift):
        moved = points.copy()
        if coordinate < points.size - 2:  # (the copy is not read: it follows the first point)
            moved.flat[coordinate] += shift
            moved[-1] = moved[0]
        return np.array(bs.evaluate(bs.make_bspline_profile(moved, "test").segment_controls, seg, u))

    h = 1e-4
    for coordinate in range(points.size):
        value = mi.Float(lathe.profile_points)
        dr.enable_grad(value)
        r, z = profile_point(value, lathe.profile_index, "bspline", mi.UInt32(seg), mi.Float(u))
        dr.set_grad(value, mi.Float(np.eye(points.size, dtype=np.float32)[coordinate]))
        derivative = np.stack([np.array(g) for g in dr.forward_to(r, z)])
        difference = (curve(coordinate, h) - curve(coordinate, -h)) / (2 * h)
        if coordinate < 2:
            assert np.abs(difference).max() > 0.1  # the first point moves the curve
        np.testing.assert_allclose(derivative, difference, atol=1e-5, err_msg=f"coordinate {coordinate}")


def test_closed_bspline_gradient_lands_on_the_first_point_in_either_orientation():
    """The same ring rendered from the clockwise and the counter-clockwise
    list (the same canonical curve, the same image): the gradients are the
    same per point, the first point's included, and the copies' are zero."""
    gradients = {}
    for name, profile in (("cw", RING_CLOCKWISE), ("ccw", RING_COUNTER_CLOCKWISE)):
        scene = lathe_scene(profile=profile, kind="bspline", resolution=16, reference="proxy")
        gradients[name] = _summed_points_gradient(scene).reshape(-1, 2)
    cw, ccw = gradients["cw"], gradients["ccw"]
    assert np.abs(cw[0]).max() > 0.5  # the first point moves the image
    assert np.all(cw[-1] == 0.0) and np.all(ccw[-1] == 0.0)
    # ccw lists the points 0, 3, 2, 1 of cw (and the copy)
    np.testing.assert_allclose(ccw[[0, 3, 2, 1]], cw[:4], rtol=1e-3, atol=1e-3 * np.abs(cw).max())


def test_refused_update_keeps_the_optimised_variable_attached():
    """An optimiser's step that the profile refuses (it intersects itself)
    raises, and the parameter goes back to the variable accepted before,
    still attached to AD: the next render differentiates, with the same
    gradient as before the refused step (once, the value went back as a
    fresh, detached copy and dr.backward failed with Dr.Jit's "does not
    depend on the input variable(s)")."""
    scene = lathe_scene(resolution=16, reference="proxy")
    params, key = _points_params(scene)
    optimizer = mi.ad.Adam(lr=0.05)
    optimizer[key] = params[key]
    params.update(optimizer)
    accepted = mi.Float(params[key])  # (the same JIT and AD variables)
    assert dr.grad_enabled(accepted)

    def gradient():
        dr.clear_grad(accepted)
        image = mi.render(scene, params, spp=4, seed=2)
        dr.backward(dr.mean(image, axis=None))
        return np.array(dr.grad(accepted))

    before = gradient()
    assert np.abs(before).max() > 0.0
    bad = np.array(params[key])
    bad[8:10] = [1.0, 0.2]  # (0.6, 1.0) dragged below the bowl: self-intersecting
    optimizer[key] = mi.Float(bad)
    with pytest.raises(ProfileError, match="intersects itself"):
        params.update(optimizer)
    restored = params[key]
    assert dr.grad_enabled(restored) and restored.index_ad == accepted.index_ad
    assert restored.index == accepted.index
    np.testing.assert_allclose(gradient(), before, rtol=1e-4, atol=1e-6 * np.abs(before).max())
    # The user goes on optimising from there (here: the optimiser back on the
    # accepted value, then a step that the profile accepts).
    optimizer[key] = params[key]
    params.update(optimizer)
    dr.backward(dr.mean(mi.render(scene, params, spp=4, seed=3), axis=None))
    optimizer.step()
    params.update(optimizer)
    assert not np.array_equal(np.array(params[key]), np.array(accepted))
