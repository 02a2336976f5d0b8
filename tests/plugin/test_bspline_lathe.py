"""B-spline lathes through the plugin: XML errors, tessellation, exact
renders against fine meshes, polyline approximations converging."""

from __future__ import annotations

import re

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from conftest import assert_watertight

from lathe_shape.plugin.shape import LatheShape
from lathe_shape.profiles.bspline import evaluate, to_polyline

#: An open B-spline goblet (ends on the axis) and a closed periodic ring.
GOBLET = "0 0, 1.6 0, 0.2 0.2, 0.2 2.0, 0.3 3.2, 2.2 3.9, 1.8 7.2, 1.7 7.2, 2.0 4.2, 0.4 3.4, 0 3.4"
RING = "1 0, 2 0, 2.5 0.5, 2 1, 1 1, 0.8 0.5, 1 0"


def sensor_dict(res: int = 48) -> dict:
    return {
        "type": "perspective", "fov": 35,
        "to_world": mi.ScalarTransform4f().look_at(origin=[0, -16, 7], target=[0, 0, 3], up=[0, 0, 1]),
        "film": {"type": "hdrfilm", "width": res, "height": res, "rfilter": {"type": "box"}},
    }


def glass_scene(kind: str, profile: str, mesh_segments: int = 256, res: int = 48) -> mi.Scene:
    return mi.load_dict({
        "type": "scene",
        "sensor": sensor_dict(res),
        "env": {"type": "constant", "radiance": {"type": "rgb", "value": [0.4, 0.4, 0.4]}},
        "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale(30),
                  "bsdf": {"type": "diffuse", "reflectance": {
                      "type": "checkerboard", "to_uv": mi.ScalarTransform4f().scale([15, 15, 1])}}},
        "glass": {"type": "lathe", "kind": kind, "profile": profile, "mesh_segments": mesh_segments,
                  "bsdf": {"type": "dielectric"}},
    })


def lathe_of(scene: mi.Scene) -> LatheShape:
    return next(s for s in scene.shapes() if isinstance(s, LatheShape))


@pytest.mark.parametrize(
    "profile, message",
    [
        ("0 0, 1 1", "an open B-spline needs at least 3 control points (both ends on the axis), got 2"),
        ("0 0, 1 0, nan 1, 0 2", "parameter 'profile', point 3: non-finite coordinate (nan, 1)"),
        ("0 0, 1 0, -1 1, 0 2", "B-spline curve crosses the axis (r < 0)"),
        ("0 0, 1 0, 1 1, 0.5 1", "an open B-spline must start and end on the axis (r = 0)"),
    ],
)
def test_bad_spline_input(profile, message):
    xml = (f"<scene version='3.0.0'><shape type='lathe' id='s'><string name='kind' value='bspline'/>"
           f"<string name='profile' value='{profile}'/></shape></scene>")
    with pytest.raises(RuntimeError, match=re.escape(message)) as info:
        mi.load_string(xml)
    assert "lathe 's': parameter 'profile'" in str(info.value)


def test_sharp_flags_rejected_for_splines():
    with pytest.raises(RuntimeError, match="sharp flags are not supported for kind 'bspline'"):
        mi.load_dict({"type": "lathe", "kind": "bspline", "profile": "0 0, 1 0 1, 1 1, 0 1"})


@pytest.mark.parametrize("profile", [GOBLET, RING], ids=["open", "closed"])
@pytest.mark.slow
def test_tessellation_is_watertight_and_on_the_curve(profile):
    shape = mi.load_dict({"type": "lathe", "kind": "bspline", "profile": profile, "mesh_segments": 32})
    mesh = shape.surface.tessellate(32)
    assert_watertight(mesh)
    # Every ring vertex lies on the exact curve (dense float64 sampling).
    seg = shape.profile.segment_controls
    t = np.linspace(0, 1, 2001)
    curve = np.concatenate([np.stack(evaluate(seg, np.full_like(t, i, dtype=int), t), axis=1)
                            for i in range(len(seg))])
    rz = np.stack([np.hypot(mesh.positions[:, 0], mesh.positions[:, 1]), mesh.positions[:, 2]], axis=1)
    rz = np.unique(rz.round(9), axis=0)  # one (r, z) per ring
    dist = np.min(np.linalg.norm(rz[:, None, :] - curve[None, :, :], axis=2), axis=1)
    assert dist.max() < 2e-3
    # Normals are unit and exact: perpendicular to the curve tangent.
    np.testing.assert_allclose(np.linalg.norm(mesh.normals, axis=1), 1.0, atol=1e-9)


@pytest.mark.slow
def test_exact_hits_match_fine_tessellation():
    scene = glass_scene("bspline", GOBLET, mesh_segments=4096, res=96)
    lathe = lathe_of(scene)
    sensor = scene.sensors()[0]
    idx = dr.arange(mi.UInt32, 96 * 96)
    pos = (mi.Point2f(mi.Float(idx % 96), mi.Float(idx // 96)) + 0.5) / 96
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
    exact = lathe.ray_intersect_exact(mi.Ray3f(ray))
    mesh = scene.ray_intersect(mi.Ray3f(ray))
    on_mesh = (mesh.is_valid() & (mesh.shape == mi.ShapePtr(lathe))).numpy()
    hit = exact.is_valid().numpy()
    assert (hit != on_mesh).mean() < 0.005
    both = hit & on_mesh
    assert np.median(np.abs(exact.t.numpy()[both] - mesh.t.numpy()[both])) < 2e-3
    n_e = np.stack([c.numpy() for c in exact.n], axis=1)[both]
    n_m = np.stack([c.numpy() for c in mesh.sh_frame.n], axis=1)[both]
    assert np.median(np.einsum("ij,ij->i", n_e, n_m)) > 0.999


@pytest.mark.slow
def test_exact_spline_render_agrees_with_fine_mesh_and_polylines_converge():
    integrator = mi.load_dict({"type": "lathe_path", "max_depth": 8, "normal_check": "none"})
    path = mi.load_dict({"type": "path", "max_depth": 8})
    spline_scene = glass_scene("bspline", GOBLET, mesh_segments=2048)
    exact = mi.render(spline_scene, spp=32, seed=5, integrator=integrator).numpy()
    mesh = mi.render(spline_scene, spp=32, seed=5, integrator=path).numpy()
    assert np.isfinite(exact).all()
    scale = exact.mean()
    assert np.abs(mesh - exact).mean() / scale < 0.06
    assert abs(mesh.mean() - exact.mean()) / scale < 0.01

    controls = lathe_of(spline_scene).profile.segment_controls
    errors = []
    for n_points in (9, 33, 257):
        poly = to_polyline(controls, n_points, "adaptive")
        text = ", ".join(f"{r:.9g} {z:.9g}" for r, z in poly)
        image = mi.render(glass_scene("polyline", text), spp=32, seed=5, integrator=integrator).numpy()
        errors.append(np.abs(image - exact).mean() / scale)
    assert errors[0] > errors[1] > errors[2]
    assert errors[2] < 0.06
