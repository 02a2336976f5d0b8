"""Watertightness of the polyline kernel over >= 1e6 rays.

Rays start outside several random closed profiles (near and far, aimed at
random points near the object, through the axis, and exactly at profile
vertices, the hardest case). Each ray is followed through all its hits
(restarting past every hit, see ``lathe_shape.tools.reference.crossing_leaks``)
and flagged as a leak when it changes sides of the surface without a
reported hit. Prints the leak count and rate.

Usage: ``python scripts/leak_test.py [n_rays]``
"""

from __future__ import annotations

import sys
from pathlib import Path

import drjit as dr
import mitsuba as mi
import numpy as np

mi.set_variant('llvm_ad_rgb')
_ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(_ROOT))
sys.path.insert(0, str(_ROOT / 'tests'))

from lathe_shape.kernels.polyline import build_polyline_data, intersect_polyline, polyline_geometry  # noqa: E402
from lathe_shape.tools import reference as ref  # noqa: E402


def kernel_callback(data):
    """``intersect(o, d, active) -> (t, valid, n)`` on numpy arrays."""
    def intersect(o, d, active):
        o32 = mi.Point3f(o.T.astype(np.float32))
        d32 = mi.Vector3f(d.T.astype(np.float32))
        hit = intersect_polyline(data, o32, d32,
                                 dr.full(mi.Float, dr.inf, len(o)),
                                 mi.Bool(active))
        p = o32 + dr.select(hit.valid, hit.t, 0) * d32
        geo = polyline_geometry(data, p, hit.seg, hit.u, False)
        return (hit.t.numpy().astype(np.float64), hit.valid.numpy(),
                geo.n.numpy().T.astype(np.float64))
    return intersect


def main() -> None:
    n_rays = int(float(sys.argv[1])) if len(sys.argv) > 1 else 1_000_000
    rng = np.random.default_rng(2024)
    profiles = ref.test_profiles(rng)
    per_profile = n_rays // len(profiles) + 1
    total_rays = total_hits = total_leaks = 0
    for name, prof in profiles:
        r0, z0, r1, z1 = prof
        n_r = -(z1 - z0)
        n_z = r1 - r0
        norm = np.hypot(n_r, n_z)
        data = build_polyline_data(r0, z0, r1, z1, n_r / norm, n_z / norm,
                                   n_r / norm, n_z / norm)
        leaks = hits = rays = 0
        done = 0
        while done < per_profile:
            m = min(200_000, per_profile - done)
            # Oversample, then keep only rays starting outside the solid
            o, d = ref.random_rays(rng, prof, 2 * m)
            o = o.astype(np.float32).astype(np.float64)
            d = d.astype(np.float32).astype(np.float64)
            keep = ~ref.inside_profile(prof, o)
            o, d = o[keep][:m], d[keep][:m]
            leak, n_hits = ref.crossing_leaks(kernel_callback(data), prof,
                                              o, d)
            rays += len(o)
            hits += int(np.sum(n_hits > 0))
            leaks += int(np.sum(leak))
            done += len(o)
        print(f'{name:13s} rays {rays:8d} hitting {hits:8d} leaks {leaks}')
        total_rays += rays
        total_hits += hits
        total_leaks += leaks
    print(f'total: {total_rays} rays, {total_hits} hitting, '
          f'{total_leaks} leaks, leak rate {total_leaks / total_hits:.2e} '
          f'(per hitting ray)')


if __name__ == '__main__':
    main()
