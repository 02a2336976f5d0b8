"""Watertightness of the polyline kernel: spawn-ray parity walk, exact vs mesh.

Rays from outside the solid profiles of ``scenes/*.csv`` (a bottle, a
sundae cup, a wine glass, and the filled wine glass's union of glass and
wine; the filled glass's open sheets, which have no inside, are left out)
are followed through every hit the way
integrators do (``si.spawn_ray`` past each hit: the restart is offset along
the geometric normal by Mitsuba's ray epsilon), on the same rays for every
query: random ones, rays aimed exactly at profile vertices and rays grazing
them (see ``lathe_shape.validation.leaks.parity_rays``). The queries: ``exact``,
the scene geometry of ``lathe_path``, which carries the walked line from
hit to hit (``lathe_shape.plugin.line_walk``); ``offset``, the lathe's own
query on the spawned rays alone; ``mesh``, Mitsuba's own mesh of the same
lathe (``--mesh-segments``); ``walk``, the kernel walked without offsets. A
ray that starts outside a closed solid must cross it an even number of
times; an odd count is a leak. A second line per profile follows rays that
refract at every hit (index 1.5, restarted with ``si.spawn_ray``), through
``lathe_path``'s geometry and through the mesh, and counts the rays that
enter while inside, leave while outside or escape from inside. Prints the
counts of each per profile and in total.

``--random-profiles`` runs the earlier measurement instead: random closed
profiles, each free stretch of a ray between hits checked by a float64
inside test (``lathe_shape.validation.leaks.crossing_leaks``).

Usage: ``python scripts/leak_test.py [--rays 1e6] [--chunk 250000]
[--mesh-segments 512] [--random-profiles] [--variant llvm_ad_rgb]``
"""

from __future__ import annotations

from pathlib import Path

from lathe_shape.validation import leaks

SCENES = Path(__file__).resolve().parents[1] / "scenes"
#: The refraction walks' counts (see lathe_shape.validation.leaks.refraction_walk).
REFRACT = ("refract", "refract_mesh")


def main() -> None:
    args = leaks.leak_test_arguments(__doc__.splitlines()[0])
    if args.random_profiles:
        rows = leaks.random_profile_leaks(args.n_rays)
        for name, rays, hits, n_leaks in rows:
            print(f"{name:13s} rays {rays:8d} hitting {hits:8d} leaks {n_leaks}")
        total = [sum(row[k] for row in rows) for k in (1, 2, 3)]
        print(f"total: {total[0]} rays, {total[1]} hitting, {total[2]} leaks, "
              f"leak rate {total[2] / max(total[1], 1):.2e} (per hitting ray)")
        return
    files = sorted(leaks.solid_profile_files(SCENES.glob("*.csv")))
    totals: dict[str, int] = {}
    for index, path in enumerate(files):
        counts = leaks.scene_parity_leaks(str(path), args.n_rays // len(files), seed=index,
                                          mesh_segments=args.mesh_segments, chunk=args.chunk, refract=True)
        for key, value in counts.items():
            totals[key] = totals.get(key, 0) + value
        print(leaks.parity_summary(path.stem, counts), flush=True)
        print(leaks.parity_summary(path.stem, counts, REFRACT), flush=True)
    print(leaks.parity_summary("total", totals))
    print(leaks.parity_summary("total", totals, REFRACT))


if __name__ == "__main__":
    main()
