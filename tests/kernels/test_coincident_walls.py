"""Liquid in a glass modelled the naive way: a closed liquid lathe whose
outer wall is the glass's inner wall (the same profile points: coincident
walls) or lies 1e-3 profile units (10 um of the 18 cm wine glass) inside
it. The Mitsuba way (one open sheet per interface, both indices on it) is
``scenes/wine_glass_filled.xml`` (tests/plugin/test_volpath.py).

Straight lines are walked as ``lathe_path`` walks them through lathes
(:meth:`ExactSceneGeometry.ray_intersect_walk`, the ray continued straight
past each crossing, no offset) and each lathe's crossings are counted
against the lathe's own exact count of the whole line
(``count_crossings_polyline``, which needs no walk): even, none lost, none
taken twice. A white furnace (index-matched, non-absorbing liquid) checks
the energy.

Measured (20k lines, seed 3): 10 um apart and coincident alike, every
line's walk equals both lathes' own counts (no odd count, none lost or
doubled). Coincident walls once ping-ponged: after lathe A's crossing at
``t`` the other lathe was asked for its first crossing after ``t``
converted to its own parameter, and that rounding decided per line whether
B's crossing at the same ``t`` was found, then whether A's was found again
(glass 2274 odd lines of 18298, liquid 3363 of 9947). The walk now orders
all crossings by ``t`` (the value each kernel returns, compared exactly),
then lathe, then each kernel's own key (docs/method.md, eq. 31); the same
holds for coincident walls of two kinds (a polyline cup and a B-spline
kernel liquid: 20k lines, none odd, lost or doubled).

White furnace (32x32, 32 spp, max_depth 64, seeds 0 and 1), liquid 1.5
inside and out (so its own surface carries no weight; the glass's does):
lathe_path 1.00005 / 0.9978 at 10 um, 1.0041 / 1.0032 coincident (within
1%, though the coincident bias of +0.4% is above the 10 um noise: the
glass's lost and doubled inner-wall crossings). Not asserted: with the
liquid in air (``ext_ior`` 1, the glass-air-liquid model) the furnace
reads 1.019 / 1.019 at 10 um and 1.020 / 1.013 coincident: a refracted or
reflected ray starts a new line with Mitsuba's spawn offset (about
1e-4 * (1 + |p|), 1.3e-3 here), larger than the 10 um gap, so the line walk
cannot help rays that turn at the glass's inner wall.

On CUDA (an H200, 2026-12-04) no walked count is odd either, but the walk
and each lathe's own count, separate kernels, round some lines' ``t``
differently (the PTX assembler may fuse a multiply and an add in one kernel
and not in the other; divisions are approximate): of 18,297 lines the
glass lost 8 and doubled 3 crossings, 10 um apart and coincident alike
(the liquid 1 and 1); coincident walls of two kinds lost or doubled
crossings on 31 of 19,257 lines of the cup and 185 of 16,257 of the
liquid. These tests are expected failures there (``CUDA_ROUNDING``), and
docs/limits.md advises the open-sheet model for liquids on CUDA.

Not tested here: "renders like the union solid". With one dielectric per
closed lathe the naive model cannot be index-matched as a whole: the
glass's inner wall keeps glass/air (1.5/1) under the liquid, and the
liquid's top needs liquid/air while its wall needs liquid/glass.
"""

from __future__ import annotations

import functools

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from conftest import CUDA_ROUNDING, SCENES

from lathe_shape.kernels.bspline import count_crossings_bspline
from lathe_shape.kernels.polyline import count_crossings_polyline
from lathe_shape.plugin.line_walk import start_walk
from lathe_shape.plugin.scene_geometry import ExactSceneGeometry
from lathe_shape.profiles import read_points
from lathe_shape.tools.filled_glass import filled_profiles
from lathe_shape.validation import leaks

GAP_10UM = 1e-3  # profile units (cm): 10 um



@functools.cache
def glass_points() -> np.ndarray:
    points, _, _ = read_points(SCENES / "wine_glass.csv")
    return points


def liquid_points(gap: float) -> np.ndarray:
    """The closed liquid: the glass's inner wall up to the fill line z = 13
    (filled_profiles' liquid wall), moved ``gap`` into the bowl (along the
    vertex normals, mitred), closed by the flat top to the axis."""
    points, sharp, _ = read_points(SCENES / "wine_glass.csv")
    wall = filled_profiles(points, sharp, 13.0)["liquid_wall"][0]
    if gap:
        seg = np.diff(wall, axis=0)
        seg /= np.linalg.norm(seg, axis=1)[:, None]
        left = np.stack([-seg[:, 1], seg[:, 0]], axis=1)  # into the bowl (glass on the right)
        n = np.vstack([left[:1], left[:-1] + left[1:], left[-1:]])
        n /= np.linalg.norm(n, axis=1)[:, None]
        n[1:-1] /= np.sum(n[1:-1] * left[1:], axis=1)[:, None]
        wall = wall + gap * n
        wall[0, 0] = 0.0
    return np.vstack([wall, [0.0, wall[-1, 1]]])


def profile_string(points: np.ndarray) -> str:
    return ", ".join(f"{float(r)!r} {float(z)!r}" for r, z in points)


def two_lathes(gap: float) -> mi.Scene:
    return mi.load_dict({
        "type": "scene",
        "glass": {"type": "lathe", "profile": profile_string(glass_points()), "mesh_segments": 16},
        "liquid": {"type": "lathe", "profile": profile_string(liquid_points(gap)), "mesh_segments": 16},
    })


def walk_lines(geometry: ExactSceneGeometry, o: np.ndarray, d: np.ndarray, steps: int):
    """Walk the lines ``o + t d`` as lathe_path does (spawn_ray with the same
    direction: the walk continues the line): per line and step the crossed
    lathe's walk index (-1: none) and its ``t`` along the line."""
    ray = mi.Ray3f(mi.Point3f(o.T.astype(np.float32)), mi.Vector3f(d.T.astype(np.float32)))
    walk, active = start_walk(len(o)), mi.Bool(True)
    lathes, ts = [], []
    for _ in range(steps):
        si, walk = geometry.ray_intersect_walk(ray, active, walk)
        # One kernel per step (unevaluated, every step's kernel would trace
        # all the steps before it, and compile anew)
        dr.eval(si, walk)
        valid = si.is_valid().numpy()
        lathes.append(np.where(valid, walk.lathe.numpy().astype(np.int64), -1))
        ts.append(np.where(valid, walk.t.numpy(), np.nan))
        if not valid.any():
            break
        ray, active = si.spawn_ray(ray.d), si.is_valid()
    return np.array(lathes).T, np.array(ts).T


def crossing_stats(gap: float, n: int, steps: int) -> dict[str, dict[str, int]]:
    """:func:`walk_stats` of the glass and the liquid ``gap`` inside it (one
    lathe set: both polylines)."""
    geometry = ExactSceneGeometry(two_lathes(gap))
    (group,) = geometry.groups  # both polylines: one set, walk indices 0, 1
    glass, liquid = glass_points(), liquid_points(gap)
    start, end = np.vstack([glass[:-1], liquid[:-1]]), np.vstack([glass[1:], liquid[1:]])
    return walk_stats(geometry, group.lathes, start, end, n, steps)


def walk_stats(geometry: ExactSceneGeometry, lathes, start: np.ndarray, end: np.ndarray, n: int,
               steps: int) -> dict[str, dict[str, int]]:
    """Per lathe (in walk-index order): lines with an odd walked count,
    with fewer / more walked crossings than the lathe's own count of the
    line, crossing lines, and repeated ``t`` values of one lathe on one
    line; ``n`` parity rays aimed at the segments ``start -> end``."""
    o, d = leaks.parity_rays(start, end, np.random.default_rng(3), n)
    walked_lathes, ts = walk_lines(geometry, o, d, steps)
    out = {}
    for k, lathe in enumerate(lathes):
        count = count_crossings_bspline if lathe.surface.kind != "polyline" else count_crossings_polyline
        own = count(lathe.surface.data, mi.Point3f(o.T.astype(np.float32)),
                    mi.Vector3f(d.T.astype(np.float32)), dr.full(mi.Bool, True, n)).numpy()
        walked = (walked_lathes == k).sum(axis=1)
        repeats = sum(int(np.sum(mine)) - len(np.unique(t[mine]))
                      for t, mine in zip(ts, walked_lathes == k, strict=True))
        out[lathe.id()] = {"odd": int(np.sum(walked % 2)), "own_odd": int(np.sum(own % 2)),
                           "lost": int(np.sum(walked < own)), "doubled": int(np.sum(walked > own)),
                           "lines": int(np.sum(own > 0)), "repeated_t": repeats,
                           "unfinished": int(np.sum(walked_lathes[:, -1] >= 0))}
    return out


def assert_each_crossing_once(stats: dict[str, dict[str, int]]) -> None:
    """Every lathe met by most lines, and on every line its walked
    crossings are its own count: even, none lost, none taken twice, every
    walk finished within its steps."""
    print(stats)
    for name, s in stats.items():
        assert s["lines"] > 9000, (name, s)
        assert s["own_odd"] == 0 and s["odd"] == 0, (name, s)
        assert s["lost"] == 0 and s["doubled"] == 0, (name, s)
        assert s["unfinished"] == 0, (name, s)


@CUDA_ROUNDING
def test_walls_10um_apart_cross_evenly_once_each():
    """20k lines (a quarter aimed at profile vertices, a quarter grazing
    them): each lathe's walked crossings are its own count of the line (even,
    none lost, none taken twice)."""
    stats = crossing_stats(GAP_10UM, 20000, 24)
    assert_each_crossing_once(stats)


@CUDA_ROUNDING
def test_coincident_walls_cross_evenly_once_each():
    """The same with the liquid's wall on the glass's inner wall (the same
    points): the walk orders crossings by t, then lathe (eq. 31), so the
    shared wall's two crossings are each taken once."""
    stats = crossing_stats(0.0, 20000, 24)
    assert_each_crossing_once(stats)


#: A straight-walled cup (polyline) and the liquid in it (a bezier profile:
#: the B-spline kernel), whose floor and wall are the cup's inner floor and
#: wall: two kinds, so two single lathes of the walk, not one set.
CUP = "0 0.1, 0.9 0.1, 0.9 1, 1 1, 1 0, 0 0"
CUP_LIQUID = ("0 0.1, 0.3 0.1, 0.6 0.1, 0.9 0.1, 0.9 0.1, 0.9 0.3, 0.9 0.6, 0.9 0.8, "
              "0.9 0.8, 0.6 0.8, 0.3 0.8, 0 0.8")


@CUDA_ROUNDING
def test_coincident_walls_of_two_kinds_cross_evenly_once_each():
    """Coincident walls of a polyline and a B-spline-kernel lathe (the
    walk's single lathes, each its own kernel with its own rounding of the
    shared wall's t): every line's walk equals both lathes' own counts."""
    scene = mi.load_dict({"type": "scene",
                          "cup": {"type": "lathe", "profile": CUP, "mesh_segments": 16},
                          "liquid": {"type": "lathe", "kind": "bezier", "profile": CUP_LIQUID,
                                     "mesh_segments": 16}})
    geometry = ExactSceneGeometry(scene)
    assert not geometry.groups and len(geometry.single) == 2
    points = [np.array([[float(v) for v in p.split()] for p in text.split(",")])
              for text in (CUP, CUP_LIQUID)]
    start = np.vstack([p[:-1] for p in points])
    end = np.vstack([p[1:] for p in points])
    stats = walk_stats(geometry, geometry.single, start, end, 20000, 16)
    assert_each_crossing_once(stats)


FURNACE = """<scene version="3.0.0">
    <integrator type="{integrator}"><integer name="max_depth" value="64"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="30"/>
        <transform name="to_world"><lookat origin="0, -52, 24" target="0, 0, 8" up="0, 0, 1"/></transform>
        <sampler type="independent"><integer name="sample_count" value="{spp}"/></sampler>
        <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/>
            <rfilter type="box"/></film>
    </sensor>
    <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
    <shape type="lathe"><string name="profile" value="{glass}"/>
        <bsdf type="dielectric"><float name="int_ior" value="1.5"/><float name="ext_ior" value="1"/></bsdf>
    </shape>
    <shape type="lathe"><string name="profile" value="{liquid}"/>
        <bsdf type="dielectric"><float name="int_ior" value="1.5"/><float name="ext_ior" value="1.5"/></bsdf>
    </shape>
</scene>"""


def furnace_mean(integrator: str, gap: float, res: int = 32, spp: int = 32) -> float:
    text = FURNACE.format(integrator=integrator, spp=spp, res=res, glass=profile_string(glass_points()),
                          liquid=profile_string(liquid_points(gap)))
    return float(mi.render(mi.load_string(text), seed=0).numpy()[..., :3].mean())


@pytest.mark.parametrize("integrator", ["lathe_path", "lathe_volpath"])
@pytest.mark.parametrize("gap", [GAP_10UM, 0.0], ids=["10um", "coincident"])
def test_index_matched_liquid_white_furnace(integrator, gap):
    """White furnace (constant sky 1): the closed glass (1.5 in air) and the
    closed index-matched liquid (1.5 on both sides), no medium: mean 1
    within 1%."""
    mean = furnace_mean(integrator, gap)
    print(integrator, gap, mean)
    assert abs(mean - 1.0) < 0.01
