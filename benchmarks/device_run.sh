#!/usr/bin/env bash
# Benchmarks and kernel tests on a lent GPU machine, through its vendor's OpenCL ICD.
#
# Usage, from the repository root on that machine: benchmarks/device_run.sh OUTDIR STEP...
# Steps: tests (the newest kernels' tests on the GPU), alltests (every kernel test file),
# tables (triple.tables: the rotation grid and one BRDF table), triple (triple.frames at 1024x768,
# 80 / 320, baked at 128²), d2i (d2i.frames at 400², 16k gathers; shadows on the device),
# d2i_cpu_layout (the same bake, the CPU's product layout: the layouts' ratio), distributed
# (engine.distributed: each method's heaviest stage on 1 worker × 1 thread against
# local:16, each worker given several chunks — d2i at 256², 64 tiles; triple's texel tiles
# 4× smaller, 181; sg's vertex batches of 16, 29 on the glossy bunny — and each run's
# timeline: ≈ 5–6 minutes by estimate from this 2-core machine's one-worker times),
# scaling (studies/core_scaling_probe.py: core-bound, memory-bound and allocation-bound work in 1–16
# processes at once, the last with and without dask's malloc setting; ≈ 1 minute),
# bake (engine.bake_device --whole: the whole bake of the Cornell box at 400², 16k gathers,
# and of bunny_grace with bake.device embree on the 16 cores and device on the GPU; issue 44).
# Results go to OUTDIR.
# The machine has Python and NumPy but no registry: the project's other wheels travel in
# .whl/ and the shared data in .devdata/ (PRT_DATA), both made here by
# benchmarks/device_prepare.sh and named in the run's carry. PoCL is not needed there.
set -u
out=${1:?usage: benchmarks/device_run.sh OUTDIR STEP...}
shift
mkdir -p "$out"
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
    --target /tmp/site .whl/*.whl || exit 1
export PYTHONPATH=/tmp/site:$PWD PRT_CL_DEVICE=gpu PRT_DATA=$PWD/.devdata PYTHONUNBUFFERED=1
mkdir -p /etc/OpenCL/vendors
echo /usr/lib/libnvidia-opencl.so.1 > /etc/OpenCL/vendors/nvidia.icd
python3 -c 'from pipeline.device import cl; d = cl.device(); print(d.name, d.version, d.global_mem_size >> 20, "MiB")' || exit 1
nvidia-smi --query-gpu=name,clocks.sm,clocks.mem,power.draw --format=csv
for step in "$@"; do
    echo "=== $step $(date +%T)"
    case $step in
    tests) timeout 60 python3 -m pytest -q -p no:cacheprovider $(ls tests/test_{bvh,d2i,\
render_pixels,wavelet_select}.py 2>/dev/null) 2>&1 | tail -25 ;;
    alltests) timeout 150 python3 -m pytest -q -p no:cacheprovider $(ls tests/test_{cl,\
fastmath,sphwavelet,wavelet_select,triple_gbuffer,triple_tables,direct,transfer,d2i,bvh,\
render_pixels}.py 2>/dev/null) 2>&1 | tail -25 ;;
    tables) timeout 30 python3 -m benchmarks run triple.tables --out "$out/tables_gpu" -- \
                --light-only ;;
    triple) timeout 120 python3 -m benchmarks run triple.frames --out "$out/triple_gpu" -- \
                --budgets 80,320 --frames 9 --bake-size 128 --workdir /tmp/bench_triple \
                2>&1 | grep -v "chunk/s" ;;
    d2i) timeout 165 python3 -m benchmarks run d2i.frames --out "$out/d2i_400_gpu" -- \
             --size 400 --workdir /tmp/bench_d2i --skip-breakdown 2>&1 | grep -v "chunk/s" ;;
    d2i_cpu_layout) timeout 90 python3 -m benchmarks run d2i.frames \
             --out "$out/d2i_400_gpu_cpu_layout" -- --size 400 --workdir /tmp/bench_d2i \
             --skip-breakdown --layout cpu 2>&1 | grep -v "chunk/s" ;;
    distributed) timeout 560 python3 -m benchmarks run engine.distributed --out "$out" -- \
             --workdir /tmp/bd --configs 1x1,local:16 --rounds 1 --max-wait 10 --only d2i \
             --only triple --only sg --size d2i=256 --set triple.texel_tile=16 \
             --set sg.fit_batch=16 ;;  # writes $out/engine.distributed.json
    scaling) timeout 120 python3 studies/core_scaling_probe.py \
             --out "$out/core_scaling_16.json" ;;
    bake) timeout 560 python3 -m benchmarks run engine.bake_device \
             --out "$out/bake_device_gpu.json" -- --repeats 1 --whole 2>&1 | grep -v "chunk/s" ;;
    *) echo "unknown step $step" ;;
    esac
done
echo "=== done $(date +%T)"
