"""One traced traversal for a bounce's two lathe queries: the nearest
crossing of a walked ray and the shadow test of another ray
(``walk_and_test_polyline``, ``ExactSceneGeometry.walk_and_test``) give
exactly what the two separate queries give, and lathe_path traces the
polyline traversal for both."""

from __future__ import annotations

import sys

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from conftest import SCENES

from lathe_shape.kernels import polyline
from lathe_shape.kernels.common import NO_CROSSING
from lathe_shape.kernels.polyline import (
    build_polyline_data,
    next_crossing_polyline,
    occluded_polyline,
    walk_and_test_polyline,
)
from lathe_shape.plugin.line_walk import start_walk
from lathe_shape.plugin.scene_geometry import ExactSceneGeometry
from lathe_shape.tools.scenes import load_scene
from lathe_shape.validation import reference as ref

PROFILES = dict(ref.test_profiles(np.random.default_rng(7)))


def _points(a: np.ndarray):
    return mi.Point3f(np.asarray(a, dtype=np.float32).T)


def _vectors(a: np.ndarray):
    return mi.Vector3f(np.asarray(a, dtype=np.float32).T)


@pytest.mark.parametrize("name", ["star7", "ring"])
def test_kernel_matches_the_two_queries(name):
    """Random walked rays (half of them going on after their first
    crossing) and random shadow rays of several lengths, some lanes off:
    bit-equal hits, places and occlusion."""
    prof = PROFILES[name]
    data = build_polyline_data(*ref.segment_points(prof))
    rng = np.random.default_rng(3)
    n = 2000
    o, d = ref.random_rays(rng, prof, n)
    so, sd = ref.random_rays(rng, prof, n)
    o, d, so, sd = _points(o), _vectors(d), _points(so), _vectors(sd)
    tmax = mi.Float(rng.uniform(0.5, 40.0, n).astype(np.float32))
    shadow_tmax = mi.Float(rng.uniform(0.1, 1.5, n).astype(np.float32))
    on, shadow_on = mi.Bool(rng.random(n) < 0.9), mi.Bool(rng.random(n) < 0.8)
    first, s_first, key_first = next_crossing_polyline(data, o, d, tmax, on)
    go_on = mi.Bool(rng.random(n) < 0.5) & first.valid
    after_s = dr.select(go_on, s_first, 0.0)
    after_key = dr.select(go_on, key_first, NO_CROSSING)
    after_t = mi.Float(rng.uniform(0.0, 2.0, n).astype(np.float32))

    hit, s, key, occluded = walk_and_test_polyline(data, o, d, tmax, on, after_s, after_key, after_t,
                                                   so, sd, shadow_tmax, shadow_on)
    hit_ref, s_ref, key_ref = next_crossing_polyline(data, o, d, tmax, on, after_s, after_key, after_t)
    occluded_ref = occluded_polyline(data, so, sd, shadow_tmax, shadow_on)
    for mine, theirs in ((hit.t, hit_ref.t), (hit.seg, hit_ref.seg), (hit.u, hit_ref.u),
                         (hit.valid, hit_ref.valid), (occluded, occluded_ref)):
        np.testing.assert_array_equal(mine.numpy(), theirs.numpy())
    # The crossing's place, where the ray is queried (elsewhere no crossing)
    for mine, theirs in ((s, s_ref), (key, key_ref)):
        np.testing.assert_array_equal(mine.numpy()[on.numpy()], theirs.numpy()[on.numpy()])
    assert 0 < occluded.numpy().sum() < n and hit.valid.numpy().any()


def _mixed_scene() -> mi.Scene:
    """A floor, a polyline cup alone of its kind, and two Bezier lathes
    (a set of their kind)."""
    bezier = "0 0, 0.333 0, 0.667 0, 1 0, 1 0, 1 0.333, 1 0.667, 1 1, 1 1, 0.667 1, 0.333 1, 0 1"
    return mi.load_dict({
        "type": "scene",
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(10)},
        "cup": {"type": "lathe", "profile": "0 0, 1 0, 1.2 2, 0 2", "mesh_segments": 16},
        "b1": {"type": "lathe", "kind": "bezier", "profile": bezier, "mesh_segments": 16,
               "to_world": mi.ScalarTransform4f().translate([2.5, 0, 0])},
        "b2": {"type": "lathe", "kind": "bezier", "profile": bezier, "mesh_segments": 16,
               "to_world": mi.ScalarTransform4f().translate([-2.5, 0, 0])},
    })


def test_scene_geometry_matches_the_two_queries():
    """Rays walked through a mixed scene, each bounce with a shadow ray
    towards a point above: the same interactions, walks and occlusion as
    ray_intersect_walk and ray_test."""
    geometry = ExactSceneGeometry(_mixed_scene())
    rng = np.random.default_rng(5)
    n = 1500
    o = rng.uniform([-4, -6, 0.2], [4, -5, 2.5], (n, 3))
    target = rng.uniform([-3.5, -1, 0.1], [3.5, 1, 2.2], (n, 3))
    ray = mi.Ray3f(_points(o), _vectors((target - o) / np.linalg.norm(target - o, axis=1, keepdims=True)))
    light = mi.Point3f(0.5, -1.0, 6.0)
    walk, walk_ref, active = start_walk(n), start_walk(n), mi.Bool(True)
    for _ in range(4):
        si_ref, walk_ref = geometry.ray_intersect_walk(ray, active, walk_ref)
        shadow = si_ref.spawn_ray_to(light)
        shadow_on = active & si_ref.is_valid()
        occluded_ref = geometry.ray_test(shadow, shadow_on)
        si, walk, occluded = geometry.walk_and_test(ray, active, walk, False, shadow, shadow_on)
        # One evaluation of everything compared (each .numpy() below would
        # otherwise trace and compile its own copy of the traversals: minutes
        # from an empty kernel cache)
        dr.eval(si_ref, walk_ref, occluded_ref, si, walk, occluded)
        for mine, theirs in ((si.t, si_ref.t), (si.p, si_ref.p), (si.n, si_ref.n),
                             (si.sh_frame.n, si_ref.sh_frame.n), (si.prim_index, si_ref.prim_index),
                             (walk.lathe, walk_ref.lathe), (walk.s, walk_ref.s), (walk.key, walk_ref.key),
                             (walk.t, walk_ref.t), (occluded, occluded_ref)):
            np.testing.assert_array_equal(mine.numpy(), theirs.numpy())
        assert (si.shape == si_ref.shape).numpy().all()
        active &= si.is_valid()
        ray = si.spawn_ray(ray.d)  # straight on: the walks continue their lines
    assert occluded_ref.numpy().any()


def test_lathe_path_traces_no_separate_shadow_traversal(monkeypatch):
    """lathe_path's render traces the polyline traversal for its shadow
    rays and its walked rays together (walk_and_test_polyline), never the
    shadow test's own traversal: the first, uncached compilation of its
    kernel compiles that code once."""
    callers = []
    init = polyline._Stack.__init__

    def record(stack):
        callers.append(sys._getframe(1).f_code.co_name)
        init(stack)

    monkeypatch.setattr(polyline._Stack, "__init__", record)
    scene = load_scene(SCENES / "wine_glass.xml", {"res": "8", "spp": "1", "max_depth": "3",
                                                   "integrator": "lathe_path"})
    mi.render(scene).numpy()
    assert callers and set(callers) == {"_first_crossing"}
