"""Watertightness of the exact B-spline lathe over many rays.

Rays from outside are followed through every hit (restarting 1e-4 of the
object's size past each one); a closed solid must be crossed an even number
of times. Prints the leak count and rate per test curve (a closed periodic
ring, an open egg, the 12-segment glass) and in total. Then the spawn-ray
parity walk of ``scripts/leak_test.py`` (restarts from ``si.spawn_ray``:
``lathe_path``'s geometry, which carries the walked line from hit to hit,
the lathe's own query on the spawned rays alone, and Mitsuba's mesh)
through the paper's B-spline glass
(``scenes/paper/glass_bspline.csv``) on a third as many rays. Last, the
offset-free walk (``next_crossing_bspline``: every query from the ray's
first origin, for the crossing after the last one) and the one-query count
(``count_crossings_bspline``) on as many rays again, shared among the test
curves and the points of every solid profile of ``scenes/*.csv`` and
``scenes/paper/*.csv`` (not the filled glass's open sheets) taken as
B-spline control points (rays aimed at random points, at the
leaves' joints and next to them).

    python scripts/leak_test_bspline.py [N_RAYS | --rays N] [--chunk 250000] [--mesh-segments 512]
                                        [--variant llvm_ad_rgb]   (default 1e6 rays in all)
"""

from __future__ import annotations

from pathlib import Path

from lathe_shape.validation import bspline_leaks, leaks

SCENES = Path(__file__).resolve().parents[1] / "scenes"
GLASS = SCENES / "paper" / "glass_bspline.csv"


def main() -> None:
    args = leaks.leak_test_arguments(__doc__.splitlines()[0], random_profiles=False)
    n_rays = args.n_rays
    curves = ("ring", "egg", "glass12")
    per_curve = n_rays // len(curves)
    total_leaks = total_entered = 0
    for index, curve in enumerate(curves):
        rate, entered = leaks.bspline_leak_rate(curve, per_curve, 100 + index)
        n_leaks = round(rate * entered)
        total_leaks += n_leaks
        total_entered += entered
        print(f"{curve:<8} rays {per_curve:>8} entering {entered:>8} leaks {n_leaks:>5} rate {rate:.2e}",
              flush=True)
    print(f"total: {per_curve * len(curves)} rays, {total_entered} entering, {total_leaks} leaks, "
          f"leak rate {total_leaks / max(total_entered, 1):.2e} (per entering ray)")
    counts = leaks.scene_parity_leaks(str(GLASS), n_rays // 3, seed=7, mesh_segments=args.mesh_segments,
                                      chunk=args.chunk, kind="bspline")
    print(leaks.parity_summary("glass_bspline", counts))
    files = sorted(str(path) for path in leaks.solid_profile_files([*SCENES.glob("*.csv"),
                                                                    *SCENES.glob("paper/*.csv")]))
    for name, counts in bspline_leaks.walk_leak_table(files, n_rays, chunk=args.chunk):
        label = str(Path(name).relative_to(SCENES)) if name.startswith(str(SCENES)) else name
        print(bspline_leaks.walk_summary(label, counts), flush=True)


if __name__ == "__main__":
    main()
