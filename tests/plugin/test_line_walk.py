"""Walking rays along lines through lathes (lathe_shape/plugin/line_walk.py):
what ``lathe_path`` carries from hit to hit so that a ray going on straight
past a lathe crossing neither skips a crossing nor takes one twice."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from lathe_shape.plugin.line_walk import continues_line, start_walk
from lathe_shape.plugin.scene_geometry import ExactSceneGeometry

CUP = "0 0, 1 0, 1.2 2, 0 2"  # a wall leaning out: its normal points down a little


def glass_on_floor() -> tuple[mi.Scene, ExactSceneGeometry]:
    """A cup standing on a square floor."""
    scene = mi.load_dict({
        "type": "scene",
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(10)},
        "glass": {"type": "lathe", "profile": CUP, "mesh_segments": 16},
    })
    return scene, ExactSceneGeometry(scene)


def rays(o, d) -> mi.Ray3f:
    o, d = np.atleast_2d(o).astype(np.float32), np.atleast_2d(d).astype(np.float32)
    return mi.Ray3f(mi.Point3f(o.T), mi.Vector3f(d.T))


def test_same_direction_within_rounding_continues():
    """A direction sent through a shading frame and back (rounding only)
    goes on along the walked line; a turned one (1e-3 rad) does not, nor
    does any ray of a walk that crossed nothing yet."""
    d = np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9])
    turned = d + 1e-3 * np.cross(d, [1.0, 0.0, 0.0])
    frame = mi.Frame3f(mi.Vector3f(0.6, 0.0, 0.8))
    roundtrip = frame.to_world(frame.to_local(mi.Vector3f(*map(float, d))))
    walk = start_walk(1)
    walk.d = mi.Vector3f(*map(float, d))
    assert not continues_line(rays([0, 0, 0], d), walk)[0]
    walk.lathe = mi.UInt32(0)
    assert continues_line(rays([0, 0, 0], d), walk)[0]
    assert continues_line(mi.Ray3f(mi.Point3f(0.0), roundtrip), walk)[0]
    assert not continues_line(rays([0, 0, 0], turned), walk)[0]


def test_walk_crosses_the_cup_and_reaches_the_floor():
    """A ray through the cup's wall, its inside and out of its far wall,
    walked with spawn_ray as lathe_path walks it: two lathe crossings, then
    the floor; the same hits (within the spawn offset) as the offset query."""
    scene, geometry = glass_on_floor()
    floor = mi.ShapePtr(next(s for s in scene.shapes() if s not in geometry.lathes))
    ray = rays([0.0, -5.0, 1.5], np.array([0.0, 1.0, -0.2]) / np.hypot(1.0, 0.2))
    walk, active = start_walk(1), mi.Bool(True)
    plain = mi.Ray3f(ray)
    shapes = []
    for _ in range(3):
        si, walk = geometry.ray_intersect_walk(ray, active, walk)
        si_plain = geometry.ray_intersect(plain, active)
        assert abs(si.t[0] - si_plain.t[0]) < 1e-3
        shapes.append("floor" if (si.shape == floor)[0] else "lathe")
        ray, plain = si.spawn_ray(ray.d), si_plain.spawn_ray(plain.d)
    assert shapes == ["lathe", "lathe", "floor"]


def test_floor_under_the_glass_wins_the_tie():
    """Inside a cup standing on a floor (its bottom and the floor coplanar),
    rays walked down through a steeply leaning wall (whose spawn offset
    moves the origin up, off the walked line) meet the floor there, never
    the cup's bottom: the other shapes are traced on the walked line too,
    and a lathe crossing must come first by more than the spawn offset."""
    scene = mi.load_dict({
        "type": "scene",
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(10)},
        "glass": {"type": "lathe", "profile": "0 0, 1 0, 3 1, 0 1", "mesh_segments": 16},
    })
    geometry = ExactSceneGeometry(scene)
    lathe = mi.ShapePtr(geometry.lathes[0])
    rng = np.random.default_rng(1)
    n = 500
    slope, height = rng.uniform(0.2, 0.45, n), rng.uniform(0.3, 0.6, n)
    d = np.stack([np.zeros(n), np.ones(n), -slope], axis=1)
    d /= np.linalg.norm(d, axis=1)[:, None]
    wall = np.stack([np.zeros(n), -(1 + 2 * height), height], axis=1)  # on the wall r = 1 + 2 z
    ray, walk, active = rays(wall - 3 * d, d), start_walk(n), mi.Bool(True)
    si, walk = geometry.ray_intersect_walk(ray, active, walk)
    assert (si.shape == lathe).numpy().all()
    si2, walk = geometry.ray_intersect_walk(si.spawn_ray(ray.d), active, walk)
    assert np.abs(si2.p.z.numpy()).max() < 1e-4
    assert not (si2.shape == lathe).numpy().any()
    assert (walk.lathe.numpy() == 0xFFFFFFFF).all()


def test_stacked_lathes_of_two_kinds_lose_no_crossing():
    """A polyline solid with a Bezier one 2e-5 above it (closer than the
    spawn offset), walked down their axis: all four crossings, whichever
    lathe the scene lists first (the tie margin holds against other shapes
    only, not between lathes)."""
    cylinder = {"type": "lathe", "profile": "0 0, 1 0, 1 1, 0 1", "mesh_segments": 16}
    bezier = {"type": "lathe", "kind": "bezier", "mesh_segments": 16,
              "profile": "0 0, 0.333 0, 0.667 0, 1 0, 1 0, 1 0.333, 1 0.667, 1 1, "
                         "1 1, 0.667 1, 0.333 1, 0 1",
              "to_world": mi.ScalarTransform4f().translate([0, 0, 1 + 2e-5])}
    for first, second in ((cylinder, bezier), (bezier, cylinder)):
        geometry = ExactSceneGeometry(mi.load_dict({"type": "scene", "a": first, "b": second}))
        o = np.array([[0.1, 0.0, 3.0], [0.2, 0.1, 3.0], [0.3, -0.2, 3.0]])
        ray, walk, active = rays(o, np.tile([0.0, 0.0, -1.0], (3, 1))), start_walk(3), mi.Bool(True)
        heights = []
        for _ in range(5):
            si, walk = geometry.ray_intersect_walk(ray, active, walk)
            dr.eval(si, walk)  # one kernel per step, not all steps again
            heights.append(np.where(si.is_valid().numpy(), si.p.z.numpy(), np.nan))
            ray = si.spawn_ray(ray.d)
        np.testing.assert_allclose(np.array(heights[:4]), np.repeat([[2 + 2e-5], [1 + 2e-5], [1], [0]], 3, 1),
                                   atol=2e-6)
        assert np.isnan(heights[4]).all()
