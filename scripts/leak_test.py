"""Watertightness of the polyline kernel over >= 1e6 rays.

Rays start outside several random closed profiles (near and far, aimed at
random points near the object, through the axis, and exactly at profile
vertices, the hardest case). Each ray is followed through all its hits
(restarting past every hit, see ``lathe_shape.tools.leaks.crossing_leaks``)
and flagged as a leak when it changes sides of the surface without a
reported hit. Prints the leak count and rate.

Usage: ``python scripts/leak_test.py [n_rays] [--variant llvm_ad_rgb]``
"""

from __future__ import annotations

import numpy as np

from lathe_shape.kernels.polyline import build_polyline_data
from lathe_shape.tools import leaks
from lathe_shape.tools import reference as ref


def main() -> None:
    args = leaks.leak_test_arguments(__doc__.splitlines()[0])
    n_rays = args.n_rays
    rng = np.random.default_rng(2024)
    profiles = ref.test_profiles(rng)
    per_profile = n_rays // len(profiles) + 1
    total_rays = total_hits = total_leaks = 0
    for name, prof in profiles:
        intersect = leaks.polyline_callback(build_polyline_data(*ref.segment_points(prof)))
        n_leaks = hits = rays = 0
        done = 0
        while done < per_profile:
            m = min(200_000, per_profile - done)
            # Oversample, then keep only rays starting outside the solid
            o, d = ref.random_rays(rng, prof, 2 * m)
            o = o.astype(np.float32).astype(np.float64)
            d = d.astype(np.float32).astype(np.float64)
            keep = ~ref.inside_profile(prof, o)
            o, d = o[keep][:m], d[keep][:m]
            leak, n_hits = leaks.crossing_leaks(intersect, prof, o, d)
            rays += len(o)
            hits += int(np.sum(n_hits > 0))
            n_leaks += int(np.sum(leak))
            done += len(o)
        print(f'{name:13s} rays {rays:8d} hitting {hits:8d} leaks {n_leaks}')
        total_rays += rays
        total_hits += hits
        total_leaks += n_leaks
    print(f'total: {total_rays} rays, {total_hits} hitting, '
          f'{total_leaks} leaks, leak rate {total_leaks / total_hits:.2e} '
          f'(per hitting ray)')


if __name__ == '__main__':
    main()
