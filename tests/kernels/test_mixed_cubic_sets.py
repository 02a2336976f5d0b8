"""Sets of cubic lathes (kernels/top_level.py) whose profiles mix the R form
(B-spline, Bezier, ...) and the R^2 form (sor, eq. 20): one traversal agrees
with each lathe's own kernel, hits and normals."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from lathe_shape.kernels.top_level import LatheSet, ProfileTable
from lathe_shape.plugin.scene_geometry import ExactSceneGeometry
from lathe_shape.surfaces import make_surface

#: (kind, points, open sheet): both forms, closed and open.
CURVES = [
    ("sor", "0 -0.5, 1.0 0, 1.2 0.5, 0.6 1.5, 0.4 2.5, 0.5 3, 0.6 3.5", False),
    ("bspline", "0 0, 1.6 0, 0.2 0.2, 0.2 2.0, 0.3 3.2, 2.2 3.9, 1.8 7.2, 1.7 7.2, 2.0 4.2, 0.4 3.4, 0 3.4",
     False),
    ("sor", "0 -0.5, 0.8 0, 1.0 0.5, 0.7 1.5, 0.9 2.2, 1.2 2.5", True),
    ("bezier", "0 0, 1.5 0, 1.6 0.3, 1.6 1.2, 1.6 1.2, 1.6 2.2, 0.4 2.4, 0.5 3.2, 0.5 3.2, "
               "0.6 3.6, 0.3 4, 0 4", False),
]


def _surface(kind: str, text: str, open_sheet: bool):
    points = np.array([[float(v) for v in item.split()] for item in text.split(",")])
    labels = [f"point {k}" for k in range(len(points))]
    return make_surface(kind, points, np.zeros(len(points), bool), labels, "test", open_sheet=open_sheet)


def _rays(n: int, lo: np.ndarray, hi: np.ndarray, seed: int = 3):
    rng = np.random.default_rng(seed)
    o = rng.uniform(lo - 3, hi + 3, size=(n, 3))
    d = rng.uniform(lo, hi, size=(n, 3)) - o
    d[::7, :2] *= 1e-3   # nearly vertical
    d[1::7, 2] *= 1e-3   # nearly horizontal
    return [np.ascontiguousarray(a.T, dtype=np.float32) for a in (o, d)]


def test_one_set_mixes_r_and_r_squared_profiles():
    surfaces = [_surface(*c) for c in CURVES]
    table = ProfileTable("bspline", [s.data for s in surfaces], [True] * len(surfaces))
    shift = [np.array([4.0 * k, 0.0, 0.0]) for k in range(len(surfaces))]
    to_world = np.stack([np.eye(4)] * len(surfaces))
    to_world[:, :3, 3] = shift
    lathes = LatheSet(table, list(range(len(surfaces))), to_world)
    o, d = _rays(40000, lathes.bounds[:3], lathes.bounds[3:])
    o_w, d_w = mi.Point3f(*o), mi.Vector3f(*d)
    hit = lathes.intersect(o_w, d_w, mi.Float(dr.inf), mi.Bool(True))
    geo, local_seg = lathes.geometry(hit, o_w, d_w)
    dr.eval(hit, geo, local_seg)
    t_ref = np.full(o.shape[1], np.inf)
    seg_ref = np.zeros(o.shape[1], np.int64)
    n_ref = np.zeros((o.shape[1], 3))
    for k, s in enumerate(surfaces):
        o_k = mi.Point3f(*(o - shift[k][:, None]).astype(np.float32))
        own = s.intersect(o_k, d_w, mi.Float(dr.inf), mi.Bool(True))
        n_own = s.geometry(o_k + own.t * d_w, own.seg, own.u).n
        t = np.where(own.valid.numpy(), own.t.numpy(), np.inf)
        take = t < t_ref
        t_ref[take] = t[take]
        seg_ref[take] = own.seg.numpy()[take]
        n_ref[take] = np.stack([c.numpy() for c in n_own], axis=1)[take]
    valid = hit.valid.numpy()
    assert np.isfinite(t_ref).mean() > 0.2
    assert (valid != np.isfinite(t_ref)).mean() < 1e-3
    both = valid & np.isfinite(t_ref)
    t = hit.t.numpy()[both]
    close = np.abs(t - t_ref[both]) <= 1e-4 * np.maximum(t_ref[both], 1.0)
    assert close.mean() > 0.999
    same = np.flatnonzero(both)[close]
    assert (local_seg.numpy()[same] != seg_ref[same]).mean() < 1e-3
    n = np.stack([c.numpy() for c in geo.n], axis=1)[same]
    assert np.percentile(np.einsum("ij,ij->i", n, n_ref[same]), 0.1) > 0.999


def test_scene_of_sor_and_bezier_lathes():
    """A scene groups lathes by kernel: two sor and two Bezier lathes make
    one set of the B-spline kernel, agreeing with the lathes' own kernels."""
    scene: dict = {"type": "scene"}
    for i, (kind, text, open_sheet) in enumerate([CURVES[0], CURVES[2], CURVES[3], CURVES[3]]):
        scene[f"lathe_{i}"] = {"type": "lathe", "kind": kind, "profile": text, "open": open_sheet,
                               "mesh_segments": 8, "reference": "proxy",
                               "to_world": mi.ScalarTransform4f().translate([4.0 * i, 0, 0])}
    scene = mi.load_dict(scene)
    geometry = ExactSceneGeometry(scene)
    kinds = [sorted({lathe.surface.kind for lathe in g.lathes}) for g in geometry.groups]
    assert kinds == [["bezier", "sor"]]
    assert not geometry.single
    box = scene.bbox()
    o, d = _rays(20000, np.array(box.min), np.array(box.max), seed=4)
    ray = mi.Ray3f(mi.Point3f(*o), mi.Vector3f(*d))
    si = geometry.ray_intersect(ray, mi.Bool(True))
    t_ref = np.full(o.shape[1], np.inf)
    for lathe in geometry.lathes:
        own = lathe.ray_intersect_exact(ray)
        t_ref = np.minimum(t_ref, np.where(own.is_valid().numpy(), own.t.numpy(), np.inf))
    valid = si.is_valid().numpy()
    assert np.isfinite(t_ref).mean() > 0.2
    assert (valid != np.isfinite(t_ref)).mean() < 1e-3
    both = valid & np.isfinite(t_ref)
    close = np.abs(si.t.numpy()[both] - t_ref[both]) <= 1e-4 * np.maximum(t_ref[both], 1.0)
    assert close.mean() > 0.999
