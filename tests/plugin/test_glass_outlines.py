"""Outlines seen through glass (``lathe_prb``'s ``glass_outlines``,
lathe_shape/plugin/glass_outlines.py, docs/method.md eqs. 41-43): a diffuse
straw in a clear tumbler, whose outlines below the rim are seen only
through the glass's wall and base. Moving the straw's profile moves those
outlines; the interior derivative alone misses them.

Measured (48x48, two scan lines per pixel, AD at 2 x 128 spp, FD at 2 x
256 spp, 2026-12-03, two runs):

| straw point | FD | AD without the term | with it | correlation with / without |
|---|---|---|---|---|
| bottom r (2) | -960 | -47 | -918, -1035 | 0.84-0.92 / 0.03 |
| top r (4) | -1146 | -485 | -1116, -1157 | 0.96 / 0.72 |
| bottom z (3) | 145 | -1 | 167, 68 (noisy: reflected views) | 0.77-0.85 / -0.17 |
"""

from __future__ import annotations

import re

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from lathe_shape.plugin.glass_outlines import (
    _Patches,
    glass_outline_backward,
    glass_outline_crossings,
    glass_outline_forward,
)
from lathe_shape.plugin.shape import scene_lathes
from lathe_shape.tools.diff_scenes import glass_scene, straw_scene
from lathe_shape.tools.gradients import finite_difference, forward_gradient, glass_gradient

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def straw():
    scene = straw_scene(resolution=48)
    # Two scan lines per pixel each way (the default, one, gives per-pixel
    # correlations of 0.89-0.94 here)
    scene.integrator().glass_outline_lines = 2
    return scene


def _gradient(scene: mi.Scene, key: str, index: int, outlines: bool) -> np.ndarray:
    """Forward-mode gradient image (channels summed), two seeds averaged."""
    integrator = scene.integrator()
    integrator.glass_outlines = outlines
    try:
        images = [forward_gradient(scene, key, index, spp=128, seed=s).sum(axis=2) for s in (3, 4)]
        return np.mean(images, axis=0)
    finally:
        integrator.glass_outlines = True


def _difference(scene: mi.Scene, key: str, index: int, h: float) -> np.ndarray:
    return np.mean([finite_difference(scene, key, index, h, spp=256, seed=s).sum(axis=2) for s in (20, 21)],
                   axis=0)


@pytest.mark.parametrize("index, what", [(2, "bottom r"), (4, "top r")])
def test_straw_outline_seen_through_glass(straw, index, what):
    """The straw's radius moves its outline, seen through the tumbler's wall:
    with the through-glass term the summed gradient is within 10% of the
    finite difference and the per-pixel correlation above 0.8 (measured
    0.84-0.92 and 0.94-0.96: the edge term's side rays and scan lines are
    few per pixel); without it the gradient misses more than half (the test
    fails without the term)."""
    fd = _difference(straw, "straw.points", index, 0.003)
    with_term = _gradient(straw, "straw.points", index, True)
    without = _gradient(straw, "straw.points", index, False)
    assert abs(with_term.sum() - fd.sum()) < 0.1 * abs(fd.sum()), (what, with_term.sum(), fd.sum())
    assert np.corrcoef(with_term.ravel(), fd.ravel())[0, 1] > 0.8
    assert abs(without.sum()) < 0.55 * abs(fd.sum())


def test_crossings_are_on_the_straw(straw):
    """The outline crossings found through the glass: past the glass's
    first wall (vertex k >= 1), on the straw and on the tumbler seen through
    itself (its far wall, its base); the refracting scan lines meet the
    straw at vertex 2 (after the tumbler's wall)."""
    integrator = straw.integrator()
    crossings = glass_outline_crossings(integrator, straw, straw.sensors()[0], seed=0)
    assert len(crossings) > 50
    assert np.all(crossings.k >= 1)
    lathes = [lathe.id() for lathe in integrator.geometry(straw).lathes]
    straw_index = lathes.index("straw")
    assert np.sum(crossings.lathe == straw_index) > 40
    refracting = crossings.lanes.reflect_at < 0
    assert np.mean(crossings.k[refracting & (crossings.lathe == straw_index)] == 2) > 0.8


def test_backward_equals_forward(straw):
    """The term's adjoint of a weighted image sum equals its forward-mode
    gradient weighted the same way (same crossings, same side samples)."""
    scene = straw
    integrator = scene.integrator()
    sensor = scene.sensors()[0]
    params = mi.traverse(scene)
    value = params["straw.points"]
    weights = np.random.default_rng(0).uniform(-1.0, 1.0, (48, 48, 3))
    forward = []
    for index in (2, 4):
        dr.enable_grad(value)
        params.update()
        tangent = np.zeros(dr.width(value), dtype=np.float32)
        tangent[index] = 1.0
        dr.set_grad(value, mi.Float(tangent))
        forward.append(float((glass_outline_forward(integrator, scene, sensor, 5, 4) * weights).sum()))
        dr.disable_grad(value)
    dr.enable_grad(value)
    params.update()
    glass_outline_backward(integrator, scene, sensor, weights, 5, 4)
    backward = np.array(dr.grad(value))[[2, 4]]
    dr.disable_grad(value)
    params.update()
    np.testing.assert_allclose(backward, forward, rtol=1e-3)
    assert min(abs(f) for f in forward) > 1.0


def test_outline_terms_need_a_pinhole_camera():
    """An orthographic camera has no image position for a world point: the
    outline terms refuse it by name; without them the gradient renders."""
    transform = mi.ScalarTransform4f
    scene = {"type": "scene", "integrator": {"type": "lathe_prb", "max_depth": 4},
             "camera": {"type": "orthographic",
                        "to_world": transform().look_at(origin=[0, -4, 0.6], target=[0, 0, 0.6],
                                                        up=[0, 0, 1]),
                        "film": {"type": "hdrfilm", "width": 16, "height": 16}},
             "glass": {"type": "lathe", "profile": "0 0, 0.5 0, 0.5 1.2, 0 1.2",
                       "bsdf": {"type": "dielectric"}},
             "sky": {"type": "constant"}}
    message = ("lathe_prb: the outline terms (parameters 'silhouette' and 'glass_outlines') need a "
               "perspective or thinlens camera, not sensor 'camera' (OrthographicCamera): set both to false "
               "for the gradient without them")
    loaded = mi.load_dict(scene)
    params = mi.traverse(loaded)
    dr.enable_grad(params["glass.points"])
    params.update()
    with pytest.raises(ValueError, match=re.escape(message)):
        dr.backward(dr.sum(mi.render(loaded, params, spp=2)))
    scene["integrator"].update(silhouette=False, glass_outlines=False)
    loaded = mi.load_dict(scene)
    params = mi.traverse(loaded)
    dr.enable_grad(params["glass.points"])
    params.update()
    dr.backward(dr.sum(mi.render(loaded, params, spp=2)))
    assert np.abs(np.array(dr.grad(params["glass.points"]))).sum() > 0.0


def test_glass_that_is_not_a_lathe():
    """A diffuse lathe behind a glass sphere (a Dirac delta that is not a
    lathe): the through-glass term finds no chain through a lathe and adds
    exactly nothing, and the gradient equals the one without the term (to
    the float32 summation order of the interior pass, which the kernels'
    grouping may change: 1e-7 seen)."""
    transform = mi.ScalarTransform4f
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "lathe_prb", "max_depth": 6},
        "camera": {"type": "perspective", "fov": 30,
                   "to_world": transform().look_at(origin=[0, -4, 0.6], target=[0, 0, 0.6], up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16}},
        "vase": {"type": "lathe", "profile": "0 0, 0.4 0, 0.5 0.6, 0.3 1.2, 0 1.2",
                 "bsdf": {"type": "diffuse"}},
        "ball": {"type": "sphere", "center": [0.3, -1.5, 0.6], "radius": 0.3, "bsdf": {"type": "dielectric"}},
        "sky": {"type": "constant"}})
    integrator = scene.integrator()
    crossings = glass_outline_crossings(integrator, scene, scene.sensors()[0], seed=0)
    assert len(crossings) == 0
    params = mi.traverse(scene)
    value = params["vase.points"]
    dr.enable_grad(value)
    params.update()
    dr.set_grad(value, mi.Float(np.eye(1, dr.width(value), 4, dtype=np.float32)[0]))
    term = glass_outline_forward(integrator, scene, scene.sensors()[0], 1, 4)
    dr.disable_grad(value)
    params.update()
    np.testing.assert_array_equal(term, 0.0)
    with_term = forward_gradient(scene, "vase.points", 4, spp=4, seed=1)
    integrator.glass_outlines = False
    without = forward_gradient(scene, "vase.points", 4, spp=4, seed=1)
    integrator.glass_outlines = True
    np.testing.assert_allclose(with_term, without, rtol=1e-5, atol=1e-9)
    assert np.abs(with_term).sum() > 0.0


def test_paths_from_a_vertex_keep_the_camera_path_depth():
    """The jump's paths go on at the grazed vertex's depth
    (``LathePRBIntegrator.sample_from``): ``max_depth`` counts from the
    camera, so at depth ``max_depth - 1`` a ray that meets a diffuse lathe
    gathers nothing more (no light sample), while the sky seen directly
    still counts."""
    scene = mi.load_dict({
        "type": "scene", "integrator": {"type": "lathe_prb", "max_depth": 3},
        "vase": {"type": "lathe", "profile": "0 0, 0.5 0, 0.5 1, 0 1", "bsdf": {"type": "diffuse"}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 0.5}}})
    integrator = scene.integrator()
    ray = mi.Ray3f(mi.Point3f([0.0, 0.0], [-3.0, -3.0], [0.5, 3.0]),
                   mi.Vector3f([0.0, 0.0], [1.0, 0.0], [0.0, 1.0]))
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(0, 2)
    for depth, lit in ((0, True), (2, False)):
        # (channels, lanes): lane 0 meets the vase, lane 1 sees the sky
        radiance = np.array(integrator.sample_from(scene, sampler, ray, mi.UInt32(depth)))
        assert (radiance[:, 0] > 0.0).all() if lit else (radiance[:, 0] == 0.0).all()
        np.testing.assert_allclose(radiance[:, 1], 0.5, rtol=1e-6)


def test_smooth_patches_of_a_profile():
    """The patches whose changes the scan looks for: a new one after every
    crease (a joint turning more than ``crease_angle``, or flagged sharp),
    none at a smoothly shaded joint; a closed loop's last patch goes on
    into its first where the loop closes smoothly."""
    def patches(profile: str, **extra) -> list[int]:
        scene = mi.load_dict({"type": "scene", "lathe": {"type": "lathe", "profile": profile, **extra}})
        return _Patches(scene_lathes(scene)).per_lathe[0].tolist()

    # (the bottom, a 90 degree corner, two 9.5 degree bends, a 90 degree corner, the top)
    assert patches("0 0, 1 0, 1 1, 0.9 1.6, 0.9 2, 0 2") == [0, 1, 1, 1, 2]
    assert patches("0 0, 1 0, 1 1, 1.05 1.5, 0 1.5") == [0, 1, 1, 2]  # (the bend: 5.7 degrees)
    assert patches("0 0, 1 0, 1 1, 1.05 1.5, 0 1.5", crease_angle=0.0) == [0, 1, 2, 3]
    assert patches("0 0, 1 0, 1 1 1, 1.05 1.5, 0 1.5") == [0, 1, 2, 3]  # (flagged sharp)
    # A closed loop (a torus-like ring of 12 points, every joint 30 degrees):
    # smooth all round at 45 degrees, one patch
    ring = ", ".join(f"{2 + 0.5 * np.cos(a):.6f} {0.5 * np.sin(a):.6f}"
                     for a in -np.arange(13) * np.pi / 6)  # (the first point again: closed)
    assert set(patches(ring, crease_angle=45.0)) == {0}
    assert patches(ring, crease_angle=20.0) == list(range(12))
    # One crease on the loop (a point flagged sharp): the patches either
    # side of it differ (merging the last into the first once erased it)
    sharp = ring.split(", ")
    sharp[3] += " 1"
    one = patches(", ".join(p if len(p.split()) == 3 else p + " 0" for p in sharp), crease_angle=45.0)
    assert one[2] != one[3] and len(set(one)) == 2
    # Flat shading (smooth false): every joint a crease, the loop's too
    assert patches("0 0, 1 0, 1 1, 1.05 1.5, 0 1.5", smooth=False) == [0, 1, 2, 3]
    assert patches(ring, crease_angle=45.0, smooth=False) == list(range(12))


def test_crease_seen_through_glass(tmp_path):
    """A solid glass puck (square corners: creases) seen from the side and
    above: its bottom edge, seen through the top and the side, moves
    the image discontinuously with the corner point. Measured (48x48, h =
    0.01, 128 spp, seeds 1-2, 2026-12-04), bottom and top corner r:
    correlation 0.97 (0.99-1.00 without the 2% of pixels where AD and FD
    differ most), interior sums within 1-10% of the FD; with the crossings
    of lathes alone (before): correlation 0.92-0.93, sums 42-79% off."""
    profile = tmp_path / "puck.csv"
    profile.write_text("0 0\n0.6 0\n0.6 0.3\n0 0.3\n")
    scene = glass_scene(str(profile), resolution=48, height=0.6)
    lathe = scene_lathes(scene)[0]
    for index in (2, 4):  # (bottom corner r, top corner r)
        check = glass_gradient(scene, lathe, index, h=0.01, spp=128, seed=1)
        ad, fd = check.trimmed()
        assert abs(fd.sum()) > 300.0
        assert check.correlation() > 0.96, index
        assert abs(ad.sum() - fd.sum()) < 0.15 * abs(fd.sum()), (index, ad.sum(), fd.sum())
