"""Turntable throughput and frame quality in one run: the per-frame time of
``lathe-turntable`` (in-process) against a bare ``mi.render`` loop over the
same poses, the error on the glass pixels of noisy and denoised low-spp
frames and of a high-spp frame against a reference, and the flicker of the
seeding policies.

    python scripts/bench_turntable.py                       # 128x128, 16 / 256 / 1024 spp
    python scripts/bench_turntable.py --resolution 512 --variant cuda_ad_rgb
"""

from lathe_shape.validation.turntable_bench import run_bench

if __name__ == "__main__":
    raise SystemExit(run_bench())
