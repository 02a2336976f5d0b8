"""Watertightness of the polyline kernel along single lines: every line
crosses a closed lathe an even number of times, and the offset-free walk
(``next_crossing_polyline``) finds each of those crossings exactly once,
also for rays aimed exactly at profile vertices and grazing corners."""

from __future__ import annotations

import os

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from conftest import SCENES
from hypothesis import given, settings
from hypothesis import strategies as st

from lathe_shape.kernels.polyline import build_polyline_data, count_crossings_polyline
from lathe_shape.surfaces import PolylineSurface
from lathe_shape.validation import leaks
from lathe_shape.validation import reference as ref

EXAMPLES = int(os.environ.get("LATHE_FUZZ_EXAMPLES", "10"))
SCENE_FILES = ["brandy_bottle.csv", "sundae_cup.csv", "wine_glass.csv"]


def scene_profile(name: str):
    """The scene profile ``name`` as its surface's ``(start, end)`` segments
    and its kernel data (smooth normals, as the lathe shape builds it)."""
    scene = mi.load_dict({"type": "scene", "lathe": {"type": "lathe", "filename": str(SCENES / name)}})
    lathe = scene.shapes()[0]
    assert isinstance(lathe.surface, PolylineSurface)
    return lathe.profile.segment_points(), lathe.surface.data


def line_crossings(data, o, d) -> np.ndarray:
    """Crossings of the whole line (rays start outside the bounding
    cylinder) per ray."""
    n = len(o)
    count = count_crossings_polyline(data, mi.Point3f(o.T.astype(np.float32)),
                                     mi.Vector3f(d.T.astype(np.float32)), dr.full(mi.Bool, True, n))
    return count.numpy().astype(np.int64)


@pytest.mark.parametrize("name", SCENE_FILES)
def test_scene_walk_has_no_odd_counts(name):
    """7000 rays per test profile (a quarter aimed exactly at vertices, a
    quarter grazing them): no odd count, and the walk meets every crossing
    of the line once."""
    (start, end), data = scene_profile(name)
    o, d = leaks.parity_rays(start, end, np.random.default_rng(11), 7000)
    total = line_crossings(data, o, d)
    crossings, stuck = leaks.crossing_walk(data, o, d)
    assert np.sum(total > 0) > 5000
    assert np.sum(total % 2) == 0
    assert not stuck.any()
    np.testing.assert_array_equal(crossings, total)


def test_random_profiles_lines_cross_evenly():
    """The same on the random closed test profiles (stars, vases, glasses,
    a ring and a cone)."""
    rng = np.random.default_rng(5)
    for name, prof in ref.test_profiles(rng):
        start, end = ref.segment_points(prof)
        data = build_polyline_data(start, end)
        o, d = leaks.parity_rays(start, end, rng, 4000)
        total = line_crossings(data, o, d)
        crossings, _ = leaks.crossing_walk(data, o, d)
        assert np.sum(total % 2) == 0, name
        np.testing.assert_array_equal(crossings, total, err_msg=name)


@settings(max_examples=EXAMPLES, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), kind=st.sampled_from(["star", "vase", "vase_tips", "glass"]),
       scale=st.sampled_from([1e-3, 1.0, 1e4]))
def test_random_profile_lines_cross_evenly_property(seed, kind, scale):
    """Random profiles of each family at several sizes: every line crosses
    them an even number of times."""
    rng = np.random.default_rng(seed)
    prof = {"star": lambda: ref.star_profile(rng, int(rng.integers(3, 40))),
            "vase": lambda: ref.vase_profile(rng, int(rng.integers(3, 40))),
            "vase_tips": lambda: ref.vase_profile(rng, int(rng.integers(3, 40)), flat_ends=False),
            "glass": lambda: ref.glass_profile(rng, int(rng.integers(2, 30)))}[kind]()
    start, end = (scale * p for p in ref.segment_points(prof))
    o, d = leaks.parity_rays(start, end, rng, 2000)
    assert np.sum(line_crossings(build_polyline_data(start, end), o, d) % 2) == 0
