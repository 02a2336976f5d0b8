"""Inverse design of lathe profiles from two rendered views.

The quick tests check the projection, the error measure and a few
optimisation steps. The full recoveries (B-spline vase below 1% of the
height, polyline glass below 2%) take 30-70 s each on a shared 2-core CPU
and run when LATHE_INVERSE_TESTS=1."""

from __future__ import annotations

import os

import numpy as np
import pytest

from lathe_shape.profiles import make_profile
from lathe_shape.tools.inverse import (
    HIDDEN_PROFILES,
    cylinder_like,
    profile_rms_error,
    project_profile,
    recover_profile,
)

FULL = pytest.mark.skipif(not os.environ.get("LATHE_INVERSE_TESTS"),
                          reason="full inverse design runs: set LATHE_INVERSE_TESTS=1")


def test_cylinder_and_projection_are_valid_profiles():
    target = HIDDEN_PROFILES["polyline"]
    start = cylinder_like(target)
    assert start.shape == target.shape
    make_profile(start)  # a valid profile
    rng = np.random.default_rng(4)
    for _ in range(20):
        moved = project_profile(start + rng.normal(0.0, 0.3, start.shape), min_radius=0.02)
        assert np.all(moved[1:-1, 0] >= 0.02) and moved[0, 0] == 0.0 and moved[-1, 0] == 0.0
        assert np.all(np.diff(moved[:, 1]) >= 0.0)


def test_profile_error_measure():
    target = HIDDEN_PROFILES["bspline"]
    assert profile_rms_error(target, target, "bspline") == pytest.approx(0.0, abs=1e-12)
    shifted = target + [0.0, 0.012]  # the whole curve 1% of its height up
    # The distance between the curves is at most the shift (less where the
    # curve is steep)
    assert 0.004 < profile_rms_error(shifted, target, "bspline") <= 0.0101


def test_few_steps_reduce_the_profile_error():
    result = recover_profile(HIDDEN_PROFILES["polyline"], "polyline", iterations=6, resolution=16, spp=4)
    start_error = profile_rms_error(cylinder_like(HIDDEN_PROFILES["polyline"]), HIDDEN_PROFILES["polyline"],
                                    "polyline")
    assert result.errors[-1] < 0.8 * start_error
    assert result.losses[-1] < result.losses[0]
    make_profile(result.points)


@FULL
def test_recover_bspline_vase():
    # Measured: 0.57% of the height (0.52% after 60 steps)
    result = recover_profile(HIDDEN_PROFILES["bspline"], "bspline", iterations=40, resolution=32, spp=8)
    assert result.errors[-1] < 0.01


@FULL
def test_recover_polyline_glass():
    # Measured: 1.0-1.4% of the height after 60 steps (README, "Differentiable lathes")
    result = recover_profile(HIDDEN_PROFILES["polyline"], "polyline", iterations=60, resolution=32, spp=8)
    assert result.errors[-1] < 0.02
