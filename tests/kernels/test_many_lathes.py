"""Scenes of many lathes: one traversal over all lathes of a kind
(kernels/top_level.py) agrees with intersecting every lathe on its own,
compiles to the same kernel whatever the lathe count, and follows moves."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from lathe_shape.plugin.scene_geometry import ExactSceneGeometry
from lathe_shape.plugin.shape import LatheShape

#: Two polyline and two B-spline profiles (one B-spline closed: a ring).
PROFILES = [
    ("polyline", "0 0, 1 0, 1 2, 0.9 2, 0.9 0.1, 0 0.1"),
    ("polyline", "0 0, 1 0, 1.2 1.5, 0.6 2.5, 0 2.5"),
    ("bspline", "0 0, 1.6 0, 0.2 0.2, 0.2 2.0, 0.3 3.2, 2.2 3.9, 1.8 7.2, 1.7 7.2, 2.0 4.2, 0.4 3.4, 0 3.4"),
    ("bspline", "1 0, 2 0, 2.5 0.5, 2 1, 1 1, 0.8 0.5, 1 0"),
]


#: A scene of many lathes (see test_kernel_does_not_grow_with_the_lathe_count).
MANY_LATHES = 32


def lathe_scene(count: int, seed: int = 1, spread: float = 4.0, env: mi.Emitter | None = None) -> mi.Scene:
    """``count`` lathes cycling through :data:`PROFILES`, randomly placed,
    turned and scaled (some mirrored, some with flipped normals), under the
    sky ``env`` (default: a new constant one)."""
    rng = np.random.default_rng(seed)
    scene: dict = {"type": "scene", "sensor": {
        "type": "perspective", "fov": 50,
        "to_world": mi.ScalarTransform4f().look_at(origin=[0, -4 * spread, 3 * spread], target=[0, 0, 0],
                                                   up=[0, 0, 1]),
        "film": {"type": "hdrfilm", "width": 32, "height": 32}},
        "env": env if env is not None else {"type": "constant"}}
    side = int(np.ceil(np.sqrt(count)))
    for i in range(count):
        kind, profile = PROFILES[i % len(PROFILES)]
        x, y = (i % side - side / 2) * spread, (i // side - side / 2) * spread
        axis = rng.normal(size=3)
        to_world = (mi.ScalarTransform4f().translate([x, y, rng.uniform(-1, 1)])
                    .rotate(axis / np.linalg.norm(axis), rng.uniform(0, 360))
                    .scale([rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6) * (-1 if i % 5 == 3 else 1),
                            rng.uniform(0.3, 0.6)]))
        scene[f"lathe_{i}"] = {"type": "lathe", "kind": kind, "profile": profile, "mesh_segments": 8,
                               "reference": "proxy", "to_world": to_world, "flip_normals": i % 7 == 2,
                               "smooth": i % 3 != 1}
    return mi.load_dict(scene)


def random_rays(scene: mi.Scene, n: int, seed: int = 2) -> mi.Ray3f:
    """Rays from around the scene, half aimed at a point inside a lathe's box."""
    rng = np.random.default_rng(seed)
    box = scene.bbox()
    lo, hi = np.array(box.min), np.array(box.max)
    o = rng.uniform(lo - 2, hi + 2, size=(n, 3))
    target = rng.uniform(lo, hi, size=(n, 3))
    lathes = [s for s in scene.shapes() if isinstance(s, LatheShape)]
    for k in range(0, n, 2):
        b = lathes[rng.integers(len(lathes))].bbox()
        target[k] = rng.uniform(np.array(b.min), np.array(b.max))
    d = target - o
    o, d = (np.ascontiguousarray(a.T, dtype=np.float32) for a in (o, d))
    return mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*d))


def one_by_one(lathes: list[LatheShape], ray: mi.Ray3f) -> mi.SurfaceInteraction3f:
    """The nearest of the lathes' own exact hits (each lathe's kernel
    evaluated on its own: lathes of one kind share that kernel)."""
    si = dr.zeros(mi.SurfaceInteraction3f, dr.width(ray.o))
    si.t = dr.inf
    for lathe in lathes:
        si_lathe = lathe.ray_intersect_exact(ray)
        dr.eval(si_lathe)
        si = dr.select(si_lathe.t < si.t, si_lathe, si)
        dr.eval(si)
    return si


def vectors(v) -> np.ndarray:
    return np.stack([c.numpy() for c in v], axis=1)


@pytest.mark.slow
def test_sets_agree_with_lathes_one_by_one():
    scene = lathe_scene(24)
    geometry = ExactSceneGeometry(scene)
    assert {g.lathes[0].surface.kind for g in geometry.groups} == {"polyline", "bspline"}
    assert not geometry.single
    # Lathes of one profile share its data (polylines: smooth or flat).
    assert sorted(g.set.table.count for g in geometry.groups) == [2, 4]
    ray = random_rays(scene, 20000)
    si = geometry.ray_intersect(ray, mi.Bool(True))
    ref = one_by_one(geometry.lathes, ray)
    hit, hit_ref = si.is_valid().numpy(), ref.is_valid().numpy()
    assert hit_ref.mean() > 0.2
    assert (hit != hit_ref).mean() < 1e-3
    both = hit & hit_ref
    t, t_ref = si.t.numpy()[both], ref.t.numpy()[both]
    close = np.abs(t - t_ref) <= 1e-4 * np.maximum(t_ref, 1.0)
    assert close.mean() > 0.999
    same = both.copy()
    same[both] = close
    shape = dr.reinterpret_array(mi.UInt32, si.shape).numpy()
    shape_ref = dr.reinterpret_array(mi.UInt32, ref.shape).numpy()
    np.testing.assert_array_equal(shape[same], shape_ref[same])
    # (The transforms round differently: a hit at a joint may change sides.)
    assert (si.prim_index.numpy()[same] != ref.prim_index.numpy()[same]).mean() < 1e-3
    for field in ("n", "p", "dp_du", "dp_dv"):
        a, b = vectors(getattr(si, field))[same], vectors(getattr(ref, field))[same]
        scale = np.maximum(np.linalg.norm(b, axis=1), 1.0)
        assert np.percentile(np.linalg.norm(a - b, axis=1) / scale, 99.9) < 1e-3, field
    sh, sh_ref = vectors(si.sh_frame.n)[same], vectors(ref.sh_frame.n)[same]
    assert np.percentile(np.einsum("ij,ij->i", sh, sh_ref), 0.1) > 0.999
    uv, uv_ref = vectors(si.uv)[same], vectors(ref.uv)[same]
    assert np.percentile(np.abs(uv - uv_ref)[:, 1], 99.9) < 1e-3
    # Shadow rays agree with the nearest hits.
    ray.maxt = mi.Float(np.where(hit_ref, ref.t.numpy() * 1.01, 1e30).astype(np.float32))
    occluded = geometry.ray_test(ray, mi.Bool(True)).numpy()
    assert (occluded != hit_ref).mean() < 1e-3
    assert np.isfinite(vectors(si.n)).all() and np.isfinite(vectors(si.sh_frame.n)).all()


def kernel_hashes(scene: mi.Scene, seed: int, integrator: mi.Integrator | None = None) -> set[str]:
    """The hashes of the kernels of a ``lathe_path`` render."""
    integrator = integrator or mi.load_dict({"type": "lathe_path", "max_depth": 3})
    with dr.scoped_set_flag(dr.JitFlag.KernelHistory, True):
        dr.kernel_history()
        mi.render(scene, spp=1, seed=seed, integrator=integrator).numpy()
        return {k["hash"] for k in dr.kernel_history() if k["type"] == dr.KernelType.JIT}


@pytest.mark.slow
def test_kernel_does_not_grow_with_the_lathe_count():
    # Both scenes exist during both renders (Mitsuba's virtual calls on
    # shapes are traced for every shape alive, whatever the scene) and share
    # their sky (a kernel holds the environment emitter's id as a literal).
    # (32 and 64 lathes: the lathe count from which the other shapes' hits
    # once took another path through plugin/scene_geometry.py)
    env = mi.load_dict({"type": "constant"})
    for few_count, many_count in ((8, 16), (MANY_LATHES, 2 * MANY_LATHES)):
        few_scene = lathe_scene(few_count, seed=3, env=env)
        many_scene = lathe_scene(many_count, seed=4, env=env)
        few = kernel_hashes(few_scene, seed=0)
        many = kernel_hashes(many_scene, seed=0)
        assert few and few == many, (few_count, many_count)


@pytest.mark.slow
def test_moving_a_lathe_moves_its_hits_without_recompiling():
    scene = lathe_scene(8, seed=5)
    integrator = mi.load_dict({"type": "lathe_path", "max_depth": 3})
    kernels = kernel_hashes(scene, 0, integrator)
    geometry = integrator.geometry(scene)
    lathe = geometry.lathes[0]
    box = lathe.bbox()
    x, y, _ = (np.array(box.min) + np.array(box.max)) / 2
    # A vertical ray down onto the lathe's centre line, from high above.
    ray = mi.Ray3f(mi.Point3f(float(x), float(y), 1000.0), mi.Vector3f(0, 0, -1))
    before = geometry.ray_intersect(ray, mi.Bool(True))
    assert before.is_valid()[0] and before.shape == mi.ShapePtr(lathe)
    moved = lathe.to_world_matrix.copy()
    moved[:3, 3] += [0.0, 0.0, -50.0]
    lathe.set_to_world(moved, scene)
    # The next render follows the move with the kernels of the first.
    assert kernel_hashes(scene, 1, integrator) == kernels
    assert integrator.geometry(scene) is geometry
    after = geometry.ray_intersect(ray, mi.Bool(True))
    assert after.is_valid()[0] and after.shape == mi.ShapePtr(lathe)
    np.testing.assert_allclose(after.t.numpy(), before.t.numpy() + 50.0, rtol=1e-5)
    # Moved aside: the same ray misses it now.
    moved[:3, 3] += [0.0, 1000.0, 0.0]
    lathe.set_to_world(moved, scene)
    assert geometry.ray_intersect(ray, mi.Bool(True)).shape != mi.ShapePtr(lathe)


def test_new_points_rebuild_the_set():
    # Two equal polyline cylinders side by side form one set; widening the
    # first through its 'points' parameter moves its hits at the next query.
    cylinder = "0 0, 1 0, 1 2, 0 2"
    scene = mi.load_dict({
        "type": "scene",
        "a": {"type": "lathe", "profile": cylinder, "reference": "proxy"},
        "b": {"type": "lathe", "profile": cylinder, "reference": "proxy",
              "to_world": mi.ScalarTransform4f().translate([10.0, 0.0, 0.0])},
    })
    integrator = mi.load_dict({"type": "lathe_path"})
    geometry = integrator.geometry(scene)
    assert len(geometry.groups) == 1
    ray = mi.Ray3f(mi.Point3f(-5.0, 0.0, 1.0), mi.Vector3f(1.0, 0.0, 0.0))
    assert geometry.ray_intersect(ray, mi.Bool(True)).t[0] == pytest.approx(4.0, rel=1e-5)
    params = mi.traverse(scene)
    params["a.points"] = mi.Float([0, 0, 2, 0, 2, 2, 0, 2])
    params.update()
    assert integrator.geometry(scene) is geometry
    assert geometry.ray_intersect(ray, mi.Bool(True)).t[0] == pytest.approx(3.0, rel=1e-5)
    # The other lathe keeps its profile.
    ray.o = mi.Point3f(5.0, 0.0, 1.0)
    assert geometry.ray_intersect(ray, mi.Bool(True)).t[0] == pytest.approx(4.0, rel=1e-5)


def test_direct_rest_interaction_equals_mitsubas():
    # The non-lathe hits' interaction computed by direct calls (no ShapePtr
    # call over every shape alive) is Mitsuba's own, field for field.
    from lathe_shape.plugin.scene_geometry import rest_interaction

    scene = mi.load_dict({
        "type": "scene",
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(40)},
        "ball": {"type": "sphere", "center": [0, 0, 5]},
        "box": {"type": "cube",
                "to_world": mi.ScalarTransform4f().translate([6, 0, 2]).rotate([1, 1, 0], 30)},
    })
    rng = np.random.default_rng(3)
    n = 20000
    o = mi.Point3f(*(rng.normal(size=(3, n)) * 10 + np.array([[0], [0], [15]])))
    ray = mi.Ray3f(o, dr.normalize(mi.Vector3f(*rng.normal(size=(3, n)))))
    expected = scene.ray_intersect(ray, mi.RayFlags.All, False, True)
    preliminary = scene.ray_intersect_preliminary(ray, False, True)
    got = rest_interaction(list(scene.shapes()), ray, preliminary, mi.Bool(True))
    assert 0.2 < expected.is_valid().numpy().mean() < 0.95
    for field in ("t", "p", "n", "uv", "dp_du", "dp_dv", "wi", "prim_index"):
        np.testing.assert_array_equal(np.array(getattr(got, field)), np.array(getattr(expected, field)),
                                      err_msg=field)
    np.testing.assert_array_equal(np.array(got.sh_frame.n), np.array(expected.sh_frame.n))
    np.testing.assert_array_equal(np.array(got.sh_frame.s), np.array(expected.sh_frame.s))
    np.testing.assert_array_equal(got.shape == expected.shape, np.full(n, True))


def test_hundreds_of_lathes_load_in_parallel():
    """Mitsuba's parallel loading nests lathe constructors on its worker
    threads; with the package's recursion limit 600 of them load (under
    Python's default limit of 1000 such a scene failed)."""
    scene = {"type": "scene"}
    for i in range(600):
        scene[f"lathe_{i}"] = {"type": "lathe", "profile": "0 0, 1 0, 1 2, 0 2", "mesh_segments": 3,
                               "reference": "proxy",
                               "to_world": mi.ScalarTransform4f().translate([3 * i, 0, 0])}
    assert len(mi.load_dict(scene, parallel=True).shapes()) == 600
