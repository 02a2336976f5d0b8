"""scripts/bench_caustics.py's arithmetic: the time-to-error ratio from the
medians and from each round alone, and the split of the glass pixels (no
rendering: results and images made by hand)."""

from __future__ import annotations

import numpy as np
import pytest

from lathe_shape.validation.caustics_bench import REGION_NAMES, split_regions, time_ratio


def _results(rounds: dict) -> dict:
    """measure()'s layout from {(method, spp): [(time, glass error) per round]}."""
    results = {}
    for key, runs in rounds.items():
        entries = [{"time": seconds, "glass": error} for seconds, error in runs]
        results[key] = {"time": float(np.median([seconds for seconds, _ in runs])),
                        "glass": float(np.mean([error for _, error in runs])), "rounds": entries}
    return results


def test_time_ratio_from_medians_and_each_round():
    results = _results({
        ("plain", 256): [(1.0, 0.1), (2.0, 0.1)],
        ("caustics", 256): [(1.2, 0.1), (2.0, 0.05)],
        # (far from the target error: never the run the ratio is read from)
        ("caustics", 4): [(0.01, 1.0), (0.01, 1.0)],
    })
    ratio, lowest, highest = time_ratio(results, "glass", 256)
    # Medians: plain 1.5 s at 0.1; caustics 1.6 s at a mean error of 0.075,
    # which reaches 0.1 in 1.6 (0.075 / 0.1)^2 = 0.9 s
    assert ratio == pytest.approx(0.9 / 1.5)
    # Round 0: 1.2 s against 1.0 s at the same error; round 1: 2.0 s at half
    # the error reaches it in a quarter of that, against plain's 2.0 s
    assert lowest == pytest.approx(0.25)
    assert highest == pytest.approx(1.2)


def test_time_ratio_reads_the_run_nearest_the_target():
    results = _results({
        ("plain", 256): [(4.0, 0.05)],
        ("caustics", 64): [(1.0, 0.1)],     # (from this run: 1.0 (0.1 / 0.05)^2 = 4.0 s)
        ("caustics", 256): [(3.0, 0.04)],  # nearer the target: 3.0 (0.04 / 0.05)^2 = 1.92 s
    })
    assert time_ratio(results, "glass", 256) == pytest.approx((0.48, 0.48, 0.48))


def test_time_ratio_lets_each_round_read_its_own_nearest_run():
    # Round 0's caustic errors are near the target at 64 spp, round 1's at
    # 256 spp: each round reads the run nearest its own plain error
    results = _results({
        ("plain", 256): [(4.0, 0.05), (4.0, 0.05)],
        ("caustics", 64): [(1.0, 0.05), (1.0, 0.2)],    # round 0: 1.0 s
        ("caustics", 256): [(4.0, 0.01), (4.0, 0.04)],  # round 1: 4.0 (0.04 / 0.05)^2 = 2.56 s
    })
    _, lowest, highest = time_ratio(results, "glass", 256)
    assert lowest == pytest.approx(1.0 / 4.0)
    assert highest == pytest.approx(2.56 / 4.0)


def test_split_regions_by_hand():
    glass = np.array([[True, True, False, False]])
    caustic = np.array([[0.5, 0.05, 0.5, 0.05]])
    reference = np.array([[1.0, 1.0, 1.0, 1.0]])
    masks = split_regions(glass, caustic, reference, share=0.1)
    assert set(masks) == set(REGION_NAMES)
    assert masks["glass_caustic"].tolist() == [[True, False, False, False]]
    assert masks["glass_other"].tolist() == [[False, True, False, False]]
    assert masks["caustic"].tolist() == [[False, False, True, False]]
    assert masks["glass"].tolist() == glass.tolist()
    assert masks["image"].all()
    # (a black reference pixel shows no caustic, whatever the caustic image holds)
    dark = split_regions(glass, caustic, np.zeros_like(reference), share=0.1)
    assert not dark["glass_caustic"].any() and dark["glass_other"].tolist() == glass.tolist()
