"""Eq. 40's weights of ``lathe_path``'s rare emitter hits through camera
chains, solved after the render kernel.

Where a path-traced caustic path reaches its diffuse vertex ``D`` through a
camera chain (camera -> Dirac deltas -> ``D`` -> Dirac deltas -> light), its
multiple importance weight needs the camera chain's solve from ``D`` (does
the light tracer's solver find this very chain?). Such hits are rare (394
of 4.2M samples of the brandy bottle at 64 spp), yet solving them inside
the render kernel cost every sample time: solved here instead, caustics
went from 1.25-1.34x plain's time to 1.22-1.29x, lower in each of five
paired runs (docs/benchmarks.md). So the kernel only records them
(:meth:`DeferredChainSolves.record`, an append buffer filled with
``dr.scatter_inc``), and :meth:`~DeferredChainSolves.put`
solves them in a kernel of their own and adds their weighted contributions
to the film at the samples' own positions, through the film's filter with
no weight of their own: the film's develop divides them by the weights its
samples left, as if the render kernel had added them.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .camera_chain import SAME_SOLUTION, solve_camera_chain

__all__ = ["DeferredChainSolves", "initial_capacity"]

#: The buffer's first size: at least this many hits ...
MIN_CAPACITY = 4096
#: ... or one per this many camera samples (measured: one in 10,000 on the
#: brandy bottle, one in 2,400 on a ball seen through a pane).
SAMPLES_PER_SLOT = 256


def initial_capacity(samples: int) -> int:
    """The buffer's size for a render of ``samples`` camera samples (a
    render whose hits overflow it runs again with room for all)."""
    return max(MIN_CAPACITY, samples // SAMPLES_PER_SLOT)


class DeferredChainSolves:
    """An append buffer of at most ``capacity`` pending emitter hits."""

    def __init__(self, capacity: int) -> None:
        self.capacity = int(capacity)
        size = self.capacity
        self.counter = dr.zeros(mi.UInt32, 1)
        self.value = dr.zeros(mi.Spectrum, size)        # contribution before eq. 40's weight
        self.light = dr.zeros(mi.Float, size)           # the light tracer's density (eq. 32)
        self.limit = dr.zeros(mi.UInt32, size)          # the chain's most vertices
        self.p = dr.zeros(mi.Point3f, size)             # D's position,
        self.n = dr.zeros(mi.Normal3f, size)            # ... geometric normal,
        self.shape = dr.zeros(mi.ShapePtr, size)        # ... shape,
        self.vertices = dr.zeros(mi.UInt32, size)       # ... and camera chain's vertices
        self.camera_d = dr.zeros(mi.Vector3f, size)     # the camera ray's direction
        self.density = dr.zeros(mi.Float, size)         # path tracing's density at D times branches

    def record(self, active: mi.Bool, value: mi.Spectrum, light: mi.Float, limit: mi.UInt32,
               p: mi.Point3f, n: mi.Normal3f, shape: mi.ShapePtr, vertices: mi.UInt32,
               camera_d: mi.Vector3f, density: mi.Float) -> None:
        """Append the lanes ``active`` (inside the render kernel); lanes
        beyond the capacity are counted, not stored (see :meth:`overflowed`)."""
        slot = dr.scatter_inc(self.counter, mi.UInt32(0), active)
        store = active & (slot < self.capacity)
        for target, source in ((self.value, value), (self.light, light), (self.limit, limit), (self.p, p),
                               (self.n, n), (self.shape, shape), (self.vertices, vertices),
                               (self.camera_d, camera_d), (self.density, density)):
            dr.scatter(target, source, slot, store)

    def count(self) -> int:
        """How many hits the render recorded (or tried to)."""
        return int(self.counter[0])

    def overflowed(self) -> bool:
        """Whether more hits came than the buffer holds."""
        return self.count() > self.capacity

    def put(self, tracer, geometry, sensor: mi.Sensor) -> None:
        """Solve the recorded hits' camera chains and add their weighted
        contributions (eq. 40) to ``sensor``'s film, which holds the render's
        samples (not yet developed)."""
        from .caustic_paths import caustic_weight

        count = min(self.count(), self.capacity)
        if count == 0:
            return
        index = dr.arange(mi.UInt32, count)

        def take(field):
            return dr.gather(type(field), field, index)

        p, n, shape, limit = take(self.p), take(self.n), take(self.shape), take(self.limit)
        camera_d, vertices = take(self.camera_d), take(self.vertices)
        active = dr.full(mi.Bool, True, count)
        # (clipped as the camera rays and the light tracer's solves are)
        solution = solve_camera_chain(geometry, tracer.camera._origin, p, n, shape, limit, active,
                                      clip=tracer.camera.clip)
        same = (solution.found & (solution.vertices == vertices)
                & (dr.norm(solution.d - camera_d) < SAME_SOLUTION))
        density = (take(self.density) * tracer.camera.direction_density(camera_d)
                   / solution.area_per_solid_angle)
        weight = caustic_weight(density, dr.select(same, tracer.chain_share * take(self.light), 0.0))
        value = take(self.value) * weight
        # The sample's film position, from its camera ray (a pinhole)
        uv, _ = tracer.camera.film_position(sensor, camera_d, active)
        film = sensor.film()
        pos = uv + mi.Vector2f(film.crop_offset())
        if film.rfilter().is_box_filter():
            pos = dr.floor(pos)  # (as Mitsuba splats box-filtered samples)
        block = film.create_block()
        channels = block.channel_count()
        zero = dr.zeros(mi.Float, count)
        values = [value.x, value.y, value.z] + [zero] * (channels - 3)  # (alpha, weight, AOVs: 0)
        block.put(pos, values, dr.all(dr.isfinite(value)))
        film.put_block(block)
