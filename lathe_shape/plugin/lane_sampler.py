"""Random numbers for a compacted subset of a render's sample lanes.

``lathe_prb``'s differential pass keeps only the camera samples whose ray
meets a surface or sees the environment
(:meth:`LathePRBIntegrator._camera_hits`), and after every vertex only the
paths that go on (:meth:`LaneSampler.take`). Its paths should
draw the numbers the primal render draws for the same samples: a gradient
then differentiates exactly the estimate a finite difference of two primal
renders compares (paired sampling; unpaired, the per-pixel agreement of the
two falls at equal spp). :func:`lane_sampler` rebuilds, for the kept lanes
alone, the state Mitsuba's ``independent`` sampler has for them after the
camera sample: each lane's PCG32 is seeded from the render's seed and the
lane's index in the wavefront, then advanced past the numbers the camera
sample took.
"""

from __future__ import annotations

import re

import drjit as dr
import mitsuba as mi

__all__ = ["LaneSampler", "camera_draws", "lane_sampler", "unpaired_lane_sampler"]


class LaneSampler:
    """The ``next_1d`` / ``next_2d`` / ``schedule_state`` part of a Mitsuba
    sampler, drawing from one PCG32 per lane, as ``independent`` does."""

    def __init__(self, rng) -> None:
        self.rng = rng

    def next_1d(self, active: mi.Bool | bool = True) -> mi.Float:
        return self.rng.next_float32(active)

    def next_2d(self, active: mi.Bool | bool = True) -> mi.Point2f:
        first = self.next_1d(active)
        return mi.Point2f(first, self.next_1d(active))

    def schedule_state(self) -> None:
        dr.schedule(self.rng.state, self.rng.inc)

    def take(self, lanes: mi.UInt32) -> LaneSampler:
        """The sampler of the lanes ``lanes`` alone (each keeps its stream)."""
        rng = mi.PCG32(self.rng)
        rng.state = dr.gather(mi.UInt64, self.rng.state, lanes)
        rng.inc = dr.gather(mi.UInt64, self.rng.inc, lanes)
        return LaneSampler(rng)


def camera_draws(sensor: mi.Sensor) -> int:
    """How many numbers Mitsuba's differentiable integrators draw per sample
    for its camera ray (``ADIntegrator.sample_rays``): the film position,
    then the aperture, the time and the wavelength where the sensor or the
    variant uses them."""
    return (2 + (2 if sensor.needs_aperture_sample() else 0)
            + (1 if sensor.shutter_open_time() > 0 else 0) + (1 if mi.is_spectral else 0))


def _base_seed(sampler: mi.Sampler) -> int | None:
    """The ``seed`` parameter of an ``independent`` sampler (None: another
    sampler, or a description without it)."""
    if sampler.class_name() != "IndependentSampler":
        return None
    found = re.search(r"base_seed = (\d+)", str(sampler))
    return int(found.group(1)) if found else None


def _streams(seed, offset: int, lanes: mi.UInt32) -> LaneSampler:
    """One PCG32 per lane of ``lanes``, seeded as ``independent`` seeds its
    wavefront: the scrambled ``seed + offset`` (an int, or a UInt32; opaque,
    so that one kernel serves all seeds) and the lane's index."""
    if isinstance(seed, int):
        seed_value = dr.opaque(mi.UInt32, (seed + offset) & 0xFFFFFFFF)
    else:
        seed_value = mi.UInt32(seed) + offset
        dr.make_opaque(seed_value)
    initstate, initseq = mi.sample_tea_32(seed_value, lanes)
    rng = mi.PCG32(dr.width(lanes))
    rng.seed(mi.UInt64(initstate), mi.UInt64(initseq))
    return LaneSampler(rng)


def lane_sampler(sensor: mi.Sensor, seed: int | mi.UInt32, lanes: mi.UInt32) -> LaneSampler | None:
    """A sampler for the wavefront lanes ``lanes`` of a render of ``sensor``
    with ``seed`` that draws what the sensor's ``independent`` sampler
    draws for them after the camera sample (None for other samplers)."""
    base = _base_seed(sensor.sampler())
    if base is None:
        return None
    sampler = _streams(seed, base, lanes)
    for _ in range(camera_draws(sensor)):
        sampler.rng.next_float32()
    return sampler


#: Added to the render's seed for :func:`unpaired_lane_sampler`'s streams.
UNPAIRED_OFFSET = 0x68E31DA4


def unpaired_lane_sampler(seed: int | mi.UInt32, count: int) -> LaneSampler:
    """``count`` lanes of an ``independent`` stream of their own, seeded from
    ``seed`` plus :data:`UNPAIRED_OFFSET` (so that it differs from the
    render's)."""
    return _streams(seed, UNPAIRED_OFFSET, dr.arange(mi.UInt32, count))
