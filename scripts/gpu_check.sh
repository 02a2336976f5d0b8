#!/bin/bash
# The CUDA checks of one short GPU session, in one run: the tests whose
# results depend most on the backend (caustics, gradients through glass, glass outlines,
# coincident walls), the caustics and gradient benchmarks, then the rest of
# the suite in the time left. Every step writes its log to OUTPUT as it
# goes, so a run stopped at a time limit still leaves what it did.
#
#     scripts/gpu_check.sh OUTPUT [SECONDS]
#
# Run it from the repository root with Mitsuba and Dr.Jit importable
# (PYTHONPATH; docs/development.md says how to carry them to a machine
# without network). SECONDS (default 450) bounds the whole run; each step
# has its own time limit inside it. Prints a summary of each step.
set -u
OUTPUT=${1:?usage: scripts/gpu_check.sh OUTPUT [SECONDS]}
BUDGET=${2:-450}
mkdir -p "$OUTPUT"
export PYTHONUNBUFFERED=1 LATHE_TEST_VARIANT=cuda_ad_rgb
START=$(date +%s)
elapsed() { echo $(( $(date +%s) - START )); }
say() { echo "[$(elapsed) s] $*"; }

nvidia-smi --query-gpu=name,driver_version --format=csv,noheader | tee "$OUTPUT/gpu.txt"
versions=$(python3 -c "import mitsuba as mi, drjit as dr; mi.set_variant('cuda_ad_rgb'); \
print('mitsuba', mi.__version__, 'drjit', dr.__version__)" 2>&1) || { echo "$versions"; exit 1; }
echo "$versions" | tee -a "$OUTPUT/gpu.txt"

say "backend-sensitive tests"
timeout 170 python3 -m pytest -v -n 15 -p no:cacheprovider -rfE \
    tests/plugin/test_caustics.py tests/plugin/test_volpath_caustics.py tests/plugin/test_gradients.py \
    tests/plugin/test_gradients_glass.py tests/plugin/test_glass_outlines.py tests/kernels/test_coincident_walls.py \
    > "$OUTPUT/tests_focused.log" 2>&1
grep -E "crashed|^FAILED|^ERROR| passed| failed" "$OUTPUT/tests_focused.log" | tail -20

say "caustics benchmark"
timeout 120 python3 scripts/bench_caustics.py --variant cuda_ad_rgb --scenes bottle --resolution 512 --repeats 5 \
    --spp 16 64 256 > "$OUTPUT/bench_caustics.log" 2>&1
grep -E "time to plain|cost per sample" "$OUTPUT/bench_caustics.log"

say "gradient benchmark"
for kind in polyline glass; do
    timeout 45 python3 scripts/bench_gradients.py --variant cuda_ad_rgb --kind "$kind" --resolution 512x512 \
        --spp 32 --repeat 5 2>&1 | tail -3
done > "$OUTPUT/bench_gradients.log"
grep "backward / primal" "$OUTPUT/bench_gradients.log"

LEFT=$(( BUDGET - $(elapsed) - 10 ))
if [ "$LEFT" -gt 60 ]; then
    say "the rest of the suite (${LEFT} s at most)"
    timeout "$LEFT" python3 -m pytest -v -n 15 -p no:cacheprovider -rfE tests \
        --ignore tests/plugin/test_caustics.py \
        --ignore tests/plugin/test_volpath_caustics.py --ignore tests/plugin/test_gradients.py \
        --ignore tests/plugin/test_gradients_glass.py --ignore tests/plugin/test_glass_outlines.py \
        --ignore tests/kernels/test_coincident_walls.py > "$OUTPUT/tests_rest.log" 2>&1
    grep -E "crashed|^FAILED|^ERROR| passed| failed" "$OUTPUT/tests_rest.log" | tail -30
fi
say "done"
