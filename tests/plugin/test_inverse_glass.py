"""Inverse design of a clear hollow glass (both walls) from renders through
the glass: the projection onto valid hollow profiles, the per-wall error
measure, and a short recovery that must cut both walls' errors and keep
the profile valid at every step. The long recovery runs when
LATHE_INVERSE_TESTS=1."""

from __future__ import annotations

import os

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from lathe_shape.profiles import make_profile
from lathe_shape.tools.inverse_glass import (
    GLASS_VIEWS,
    HIDDEN_HOLLOW,
    START_BOTTOMS,
    VALIDATION_SEED,
    _HollowLoss,
    hollow_cylinder_like,
    hollow_valid,
    project_hollow,
    recover_hollow,
    wall_rms_errors,
)

LONG = pytest.mark.skipif(not os.environ.get("LATHE_INVERSE_TESTS"),
                          reason="long hollow-glass recovery: set LATHE_INVERSE_TESTS=1")


def test_start_and_target_are_valid_hollow_profiles():
    target, n_outer = HIDDEN_HOLLOW["wine_glass"]
    assert len(target) >= 16
    start = hollow_cylinder_like(target, n_outer)
    assert start.shape == target.shape
    for points in (target, start):
        assert hollow_valid(points, n_outer, 0.02)
        make_profile(points)
    assert wall_rms_errors(target, target, n_outer) == pytest.approx((0.0, 0.0), abs=1e-12)
    outer, inner = wall_rms_errors(start, target, n_outer)
    assert outer > 0.05 and inner > 0.05


def test_projection_keeps_the_walls_apart():
    target, n_outer = HIDDEN_HOLLOW["wine_glass"]
    start = hollow_cylinder_like(target, n_outer)
    rng = np.random.default_rng(7)
    for _ in range(200):
        moved = project_hollow(start + rng.normal(0.0, 0.05, start.shape), n_outer, 0.02, 0.02)
        assert hollow_valid(moved, n_outer, 0.02)
        assert moved[0, 0] == 0.0 and moved[-1, 0] == 0.0
    # A projected valid profile is itself
    assert np.array_equal(project_hollow(target, n_outer, 0.02, 0.02), target)
    assert np.array_equal(project_hollow(target, n_outer, 0.02, 0.02, max_axis_slope=1.0), target)


def test_projection_limits_the_slope_at_the_axis():
    # A narrow spike along the axis (the axis point 0.25 below a neighbour
    # at radius 0.06, as recoveries ended in, unseen at 32x32 pixels) is
    # raised to the slope limit; without a limit it stays
    target, n_outer = HIDDEN_HOLLOW["wine_glass"]
    spiked = target.copy()
    spiked[-2] = (0.06, 0.93)
    spiked[-1, 1] = 0.68
    spiked[1] = (0.06, 0.0)
    spiked[0, 1] = -0.2
    assert np.array_equal(project_hollow(spiked, n_outer, 0.02, 0.02), spiked)
    moved = project_hollow(spiked, n_outer, 0.02, 0.02, max_axis_slope=1.0)
    assert moved[-1, 1] == pytest.approx(0.93 - 0.06) and moved[0, 1] == pytest.approx(-0.06)
    assert np.array_equal(moved[1:-1], spiked[1:-1])
    assert hollow_valid(moved, n_outer, 0.02)
    rng = np.random.default_rng(3)
    start = hollow_cylinder_like(target, n_outer)
    for _ in range(200):
        moved = project_hollow(start + rng.normal(0.0, 0.05, start.shape), n_outer, 0.02, 0.02, 0.5)
        assert hollow_valid(moved, n_outer, 0.02)
        inner_rise = moved[-2, 1] - moved[-1, 1]
        outer_rise = moved[1, 1] - moved[0, 1]
        assert inner_rise <= 0.5 * moved[-2, 0] + 1e-12 and outer_rise <= 0.5 * moved[1, 0] + 1e-12


def test_recover_hollow_refuses_bad_starts():
    target, n_outer = HIDDEN_HOLLOW["wine_glass"]
    for starts in ((), (0.4, 1.0), (0.0,), (float("nan"),)):
        with pytest.raises(ValueError) as error:
            recover_hollow(target, n_outer, starts=starts)
        assert str(error.value) == (
            "recover_hollow: starts must be fractions of the height strictly between 0 and 1 (one descent "
            f"from each), got {tuple(starts)!r}")
    for slope in (-0.5, float("nan"), float("inf")):
        with pytest.raises(ValueError) as error:
            recover_hollow(target, n_outer, axis_slope=slope)
        assert str(error.value) == (
            f"recover_hollow: axis_slope must be None or finite and >= 0, got {slope!r}")
    with pytest.raises(ValueError) as error:
        recover_hollow(target, n_outer, validation=(8, 4))
    assert str(error.value) == "recover_hollow: validation must be (resolution >= 16, spp >= 1), got (8, 4)"
    for refine in ((8, 4, 3), (32, 0, 3), (32, 4, 0), (32, 4)):
        with pytest.raises(ValueError) as error:
            recover_hollow(target, n_outer, refine=refine)
        assert str(error.value) == ("recover_hollow: refine must be None or (resolution >= 16, spp >= 1, "
                                    f"steps >= 1), got {refine!r}")


@pytest.mark.slow
def test_recovery_keeps_the_descent_whose_validation_renders_agree_best_and_refines_it():
    # Two short descents from different inside bottoms; the kept one is
    # the one whose validation renders (other pixel samples, renders only)
    # have the lowest loss, recomputed here from a fresh scene; then three
    # refinement steps at 24x24 pixels continue from its end
    target, n_outer = HIDDEN_HOLLOW["wine_glass"]
    starts, validation = (0.4, 0.55), (24, 4)
    result = recover_hollow(target, n_outer, iterations=3, resolution=16, spp=2, seed=5, starts=starts,
                            validation=validation, refine=(24, 4, 3))
    assert [descent.bottom for descent in result.descents] == list(starts)
    losses = [descent.validation_loss for descent in result.descents]
    assert all(np.isfinite(losses)) and losses[0] != losses[1]
    kept = int(np.argmin(losses))
    assert result.kept == kept and result.validation_loss == losses[kept]
    # The kept descent's 3 steps, then the refinement's 3
    assert result.refine_start == 3 and len(result.errors) == len(result.losses) == 6 and all(result.valid)
    assert result.errors[2] == result.descents[kept].errors
    assert not np.array_equal(result.points, result.descents[kept].points)
    assert hollow_valid(result.points, n_outer, 0.02)
    recovered = wall_rms_errors(result.points, target, n_outer)
    assert recovered == pytest.approx(result.errors[-1], abs=1e-12)
    judge = _HollowLoss(target, *validation, views=GLASS_VIEWS, max_depth=8,
                        seed=5 + VALIDATION_SEED, levels=5, frequency=2.5, silhouette_weight=0.0,
                        min_thickness=0.02)
    with dr.suspend_grad():
        again = float(np.array(judge(mi.Float(result.descents[kept].points.ravel().astype(np.float32))))[0])
    assert again == pytest.approx(result.validation_loss, rel=1e-5)
    # The images are the descents' (16x16, their pixel samples), of the
    # refined points
    again = _HollowLoss(target, 16, 2, GLASS_VIEWS, 8, 5, 5, 2.5, 0.0, 0.02)
    assert again.write(result.points, n_outer)
    for image, fresh in zip(result.after, again.images(), strict=True):
        assert image.shape[:2] == (16, 16) and np.array_equal(image, fresh)
    # The start's inside bottom is where the kept descent began, and the
    # images before are of that start
    start = hollow_cylinder_like(target, n_outer, bottom=starts[kept])
    assert wall_rms_errors(start, target, n_outer) == pytest.approx(result.start_errors, abs=1e-12)
    assert again.write(start, n_outer)
    for image, fresh in zip(result.before, again.images(), strict=True):
        assert image.shape[:2] == (16, 16) and np.array_equal(image, fresh)
    assert START_BOTTOMS == (0.4, 0.45, 0.5)


def test_resampled_loss_draws_new_samples_and_is_zero_at_the_target():
    # Every evaluation renders the targets again with its new pixel
    # samples: zero at the hidden profile each time, and another profile's
    # loss changes from one evaluation to the next (the fixed loss repeats)
    target, n_outer = HIDDEN_HOLLOW["wine_glass"]
    start = hollow_cylinder_like(target, n_outer, bottom=0.45)
    points = [mi.Float(np.asarray(p, dtype=np.float32).ravel()) for p in (target, start)]
    for resample in (True, False):
        loss = _HollowLoss(target, 16, 2, GLASS_VIEWS, 8, 3, 5, 2.5, 4.0, 0.02, resample=resample)
        with dr.suspend_grad():
            values = [float(np.array(loss(p))[0]) for p in (*points, *points)]
        assert values[0] < 1e-10 and values[2] < 1e-10
        assert values[1] > 0.0 and values[3] > 0.0
        assert (values[1] != values[3]) == resample
        assert loss.seed == (3 + 4 * 3000 if resample else 3)


@pytest.mark.slow
def test_short_hollow_recovery_cuts_both_errors_and_stays_valid():
    # 20 steps at 32x32 pixels, 8 spp, three views, inside the smooth
    # emissive sphere, with the views' silhouettes (weight 4). Measured
    # (seed 0): outer wall 7.84% -> 3.49-3.59%, inner wall 6.46% ->
    # 1.42-1.87% of the height, 8 s; from the renders alone 5.41-6.19% and
    # 4.25-4.45% (the gradients' last digits, the reverse pass's order of
    # summation, grow into these differences within 20 steps: two versions
    # whose gradients agree to 1e-6 ended at 5.72% and 6.19%)
    target, n_outer = HIDDEN_HOLLOW["wine_glass"]
    errors = {}
    for weight in (4.0, 0.0):
        result = recover_hollow(target, n_outer, iterations=20, resolution=32, spp=8,
                                silhouette_weight=weight, starts=(0.4,), refine=None)
        start_outer, start_inner = result.start_errors
        errors[weight] = outer, inner = result.errors[-1]
        print(f"hollow glass, short, silhouette weight {weight:g}: outer {100 * start_outer:.2f}% -> "
              f"{100 * outer:.2f}%, inner {100 * start_inner:.2f}% -> {100 * inner:.2f}% of height, "
              f"{result.seconds:.1f} s")
        assert all(result.valid) and len(result.valid) == 20
        make_profile(result.points)
        cut = 1.3 if weight else 1.2
        assert outer < start_outer / cut
        assert inner < start_inner / cut
        # The uphill guard: an evaluation more than 10% above the best so far
        # is taken back to the best profile (the errors before each step:
        # the start's, then the step before's)
        before = [result.start_errors] + result.errors[:-1]
        for k in range(1, len(result.losses)):
            best = int(np.argmin(result.losses[:k]))
            if result.losses[k] > 1.1 * result.losses[best]:
                assert result.errors[k] == pytest.approx(before[best], abs=1e-12)
    outer, inner = errors[4.0]
    assert outer < result.start_errors[0] / 1.8 and inner < result.start_errors[1] / 3.0
    assert outer < 0.8 * errors[0.0][0] and inner < 0.8 * errors[0.0][1]  # the silhouettes help


@LONG
def test_long_hollow_recovery():
    # The script's defaults: three descents of 120 steps (silhouette weight
    # 4, uphill guard 0.1, axis slope 1) from inside bottoms at 0.4, 0.45
    # and 0.5 of the height, the one whose validation renders agree best
    # kept, then refined for 100 steps at 64x64 pixels, 64 spp, new pixel
    # samples every step. Measured (2026-12-05): the kept descents of seeds
    # 0-17 refined to 0.31-0.87% / 0.16-0.96% of the height (outer / inner
    # wall); end to end 0.71 / 0.87, 0.69 / 0.51, 0.36 / 0.37%, 172-185 s
    # each (docs/differentiable.md)
    target, n_outer = HIDDEN_HOLLOW["wine_glass"]
    for seed in range(3):
        result = recover_hollow(target, n_outer, iterations=120, resolution=32, spp=8, seed=seed)
        outer, inner = result.errors[-1]
        print(f"hollow glass, long, seed {seed}: outer {100 * outer:.2f}%, inner {100 * inner:.2f}% "
              f"of height, {result.seconds:.1f} s")
        assert all(result.valid) and result.refine_start == 120
        assert outer < 0.01 and inner < 0.01
