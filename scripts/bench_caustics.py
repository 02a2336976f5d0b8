"""Caustics of ``lathe_path`` (and of ``lathe_volpath`` in the scenes with
media): plain path tracing against path tracing with light-traced caustic
paths (``caustics``), error on the caustic region, the glass pixels and the
whole image against a high-spp plain reference, and the time to reach
plain's 256 spp error.

    python scripts/bench_caustics.py                           # bottle, wine glass, 256x256
    python scripts/bench_caustics.py --scenes sundae_cup paper_bspline pov_samples --unbiased 1024
    python scripts/bench_caustics.py --scenes wine_glass_filled green_bottle   # lathe_volpath
"""

from lathe_shape.validation.caustics_bench import run_bench

if __name__ == "__main__":
    raise SystemExit(run_bench())
