"""The camera-chain solver of caustics seen through glass (eqs. 37-39):
chains of 1 (into a glass block), 2 (a glass slab) and 4 (two slabs) interfaces,
against closed forms in float64 NumPy: the camera direction found, the
chain's length and the area per solid angle of eq. 39; and what it must
refuse."""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

CAMERA = np.array([-0.4, -3.0, 5.0])

#: Glass slabs (bottom z, thickness, IOR): disks of radius 4 made as lathes.
SLABS = [(1.0, 0.2, 1.5), (2.0, 0.3, 1.33)]


def slab(z: float, thickness: float, bsdf: dict) -> dict:
    return {"type": "lathe", "profile": f"0 0, 4 0, 4 {thickness}, 0 {thickness}",
            "to_world": mi.ScalarTransform4f().translate([0, 0, z]), "bsdf": bsdf}


def scene_of(shapes: dict) -> mi.Scene:
    film = {"type": "hdrfilm", "width": 8, "height": 8}
    return mi.load_dict({"type": "scene", "integrator": {"type": "lathe_path"}, **shapes,
                         "sensor": {"type": "perspective", "film": film}})


def solve(scene: mi.Scene, points: np.ndarray, normal, target: str, max_vertices: int = 8):
    from lathe_shape.plugin.camera_chain import solve_camera_chain

    integrator = scene.integrator()
    shape = [s for s in scene.shapes() if s.id() == target][0]
    count = len(points)
    shapes = dr.gather(mi.ShapePtr, mi.ShapePtr(shape), dr.zeros(mi.UInt32, count))
    p = mi.Point3f(*[mi.Float(c) for c in points.T])
    solution = solve_camera_chain(integrator.geometry(scene), mi.Point3f(*CAMERA.tolist()), p,
                                  mi.Normal3f(*normal), shapes, mi.UInt32(max_vertices), mi.Bool(True))
    return (np.array(solution.found), np.array(solution.d).reshape(3, -1).T, np.array(solution.vertices),
            np.array(solution.area_per_solid_angle))


def stack_landing(d: np.ndarray, layers: list) -> np.ndarray:
    """Where the camera ray ``d`` (unit, downwards) lands on z = 0 after
    refracting through horizontal slabs ``layers`` (float64)."""
    horizontal = np.hypot(d[0], d[1])
    sin_air = horizontal
    tan = lambda s: s / np.sqrt(1.0 - s * s)  # noqa: E731
    distance = CAMERA[2] * tan(sin_air)       # as if all air
    for _, thickness, ior in layers:          # each slab replaces air by glass
        distance += thickness * (tan(sin_air / ior) - tan(sin_air))
    return np.array([CAMERA[0] + d[0] / horizontal * distance, CAMERA[1] + d[1] / horizontal * distance, 0.0])


def mirror_landing(d: np.ndarray, mirror_z: float, plane_z: float) -> np.ndarray:
    t = (mirror_z - CAMERA[2]) / d[2]
    m = CAMERA + t * d
    r = np.array([d[0], d[1], -d[2]])
    return m + (plane_z - mirror_z) / r[2] * r


def direction_to(landing, target: np.ndarray) -> np.ndarray:
    """The camera direction whose ray lands on ``target`` (Newton in float64,
    derivatives by central differences of the closed form)."""
    d = (target - CAMERA) / np.linalg.norm(target - CAMERA)
    for _ in range(50):
        e1, e2 = frame(d)
        q = landing(d)
        jac = np.stack([(landing(unit(d + 1e-7 * e)) - landing(unit(d - 1e-7 * e)))[:2] / 2e-7
                        for e in (e1, e2)], axis=1)
        step = np.linalg.solve(jac, (q - target)[:2])
        d = unit(d - step[0] * e1 - step[1] * e2)
    return d


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.linalg.norm(v)


def frame(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    e1 = unit(np.cross(d, [0.0, 0.0, 1.0]))
    return e1, np.cross(d, e1)


def area_per_solid_angle(landing, d: np.ndarray) -> float:
    """Eq. 39 in float64: |det| of the landing point (on a horizontal plane)
    against gnomonic coordinates around ``d``, where they are solid angle."""
    e1, e2 = frame(d)
    h = 1e-6
    columns = [(landing(unit(d + h * e)) - landing(unit(d - h * e)))[:2] / (2 * h) for e in (e1, e2)]
    return abs(np.linalg.det(np.stack(columns, axis=1)))


@pytest.mark.parametrize("slabs", [1, 2])
def test_glass_slabs_two_and_four_interfaces(slabs):
    layers = SLABS[:slabs]
    shapes = {f"slab{i}": slab(z, t, {"type": "dielectric", "int_ior": ior, "ext_ior": 1.0})
              for i, (z, t, ior) in enumerate(layers)}
    shapes["floor"] = {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale([10, 10, 1])}
    scene = scene_of(shapes)
    rng = np.random.default_rng(3)
    points = np.column_stack([rng.uniform(-1.5, 1.5, 64), rng.uniform(-1.5, 1.5, 64), np.zeros(64)])
    found, d, vertices, area = solve(scene, points, (0.0, 0.0, 1.0), "floor")
    assert found.all()
    assert (vertices == 2 * slabs).all()

    def landing(direction):
        return stack_landing(direction, layers)

    check(landing, points, d, area)


def check(landing, points: np.ndarray, d: np.ndarray, area: np.ndarray) -> None:
    """The solver's directions land on the points and its areas per solid
    angle (eq. 39) are the closed form's at the exact solution. (The
    solver stops within 1e-4 of the camera's distance on its own traced
    chain; float32 and the rays' spawn offsets at each vertex, about 1e-5
    along the normal, move that chain by up to 1e-4 of the distance.)"""
    for i, point in enumerate(points):
        distance = np.linalg.norm(point - CAMERA)
        assert np.linalg.norm(landing(d[i] / np.linalg.norm(d[i])) - point) < 2.5e-4 * distance
        expected = direction_to(landing, point)
        assert np.linalg.norm(d[i] - expected) < 3e-4
        assert area[i] == pytest.approx(area_per_solid_angle(landing, expected), rel=3e-3)


def test_one_interface_into_glass():
    """Camera -> the flat top of a thick glass slab (z 0 .. 2) -> a plane
    inside it at z = 1."""
    shapes = {"block": slab(0.0, 2.0, {"type": "dielectric", "int_ior": 1.5, "ext_ior": 1.0}),
              "inside": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0.0, 0.0, 1.0])
                         @ mi.ScalarTransform4f().scale([3, 3, 1])}}
    scene = scene_of(shapes)
    rng = np.random.default_rng(4)
    points = np.column_stack([rng.uniform(-1.5, 1.5, 32), rng.uniform(-1.5, 1.5, 32), np.ones(32)])
    found, d, vertices, area = solve(scene, points, (0.0, 0.0, 1.0), "inside")
    assert found.all()
    assert (vertices == 1).all()

    def landing(direction):
        # 3 above the block's top (z = 2) in air, then 1 down in glass
        horizontal = np.hypot(direction[0], direction[1])
        sin_glass = horizontal / 1.5
        distance = 3.0 * horizontal / -direction[2] + sin_glass / np.sqrt(1.0 - sin_glass**2)
        return np.array([CAMERA[0] + direction[0] / horizontal * distance,
                         CAMERA[1] + direction[1] / horizontal * distance, 1.0])

    check(landing, points, d, area)


def test_refusals():
    """No chain: D seen straight (no vertex), a chain longer than allowed,
    and a D on another shape than the one the chain lands on."""
    shapes = {"slab": slab(1.0, 0.2, {"type": "dielectric"}),
              "floor": {"type": "rectangle", "to_world": mi.ScalarTransform4f().scale([10, 10, 1])},
              "other": {"type": "rectangle", "to_world": mi.ScalarTransform4f().translate([0, 0, -5])}}
    scene = scene_of(shapes)
    seen_straight = np.array([[8.0, 8.0, 0.0]])   # beyond the slab's edge
    assert not solve(scene, seen_straight, (0.0, 0.0, 1.0), "floor")[0].any()
    under = np.array([[0.3, 0.2, 0.0]])
    assert solve(scene, under, (0.0, 0.0, 1.0), "floor")[0].all()
    assert not solve(scene, under, (0.0, 0.0, 1.0), "floor", max_vertices=1)[0].any()
    assert not solve(scene, under, (0.0, 0.0, 1.0), "other")[0].any()
