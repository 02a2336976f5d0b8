"""Watertightness of the exact B-spline lathe over many rays.

Rays from outside are followed through every hit (restarting 1e-4 of the
object's size past each one); a closed solid must be crossed an even number
of times. Prints the leak count and rate per test curve (a closed periodic
ring, an open egg, the 12-segment glass) and in total.

    python scripts/leak_test_bspline.py [N_RAYS]      (default 1e6 in all)
"""

from __future__ import annotations

import sys
from pathlib import Path

import mitsuba as mi

mi.set_variant("llvm_ad_rgb")
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from test_bspline import _leak_rate  # noqa: E402


def main() -> None:
    n_rays = int(float(sys.argv[1])) if len(sys.argv) > 1 else 1_000_000
    curves = ("ring", "egg", "glass12")
    per_curve = n_rays // len(curves)
    total_leaks = total_entered = 0
    for index, curve in enumerate(curves):
        rate, entered = _leak_rate(curve, per_curve, 100 + index)
        leaks = round(rate * entered)
        total_leaks += leaks
        total_entered += entered
        print(f"{curve:<8} rays {per_curve:>8} entering {entered:>8} leaks {leaks:>5} rate {rate:.2e}",
              flush=True)
    print(f"total: {per_curve * len(curves)} rays, {total_entered} entering, {total_leaks} leaks, "
          f"leak rate {total_leaks / max(total_entered, 1):.2e} (per entering ray)")


if __name__ == "__main__":
    main()
