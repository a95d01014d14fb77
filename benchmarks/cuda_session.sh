#!/usr/bin/env bash
# Issue #34's measurements on a lent GPU machine (the workplace's `device` tool), prepared in advance.
#
# The device machine is bare (Python 3.12, numpy, pytest, matplotlib; no warp-lang, usd-core or meshio)
# and reaches nothing outside it; one call carries at most 64 MiB (working tree + carried paths), and the
# warp-lang wheel alone is ~149 MB. So the wheels travel in parts over several calls made back to back
# (the machine stays warm ~30 s after a call; ignored paths a call does not carry are kept there):
#
#   here:    bash benchmarks/cuda_session.sh pack          # wheels -> .gpu1/ .gpu2/ ... (<= 44 MiB each)
#   device:  run(command="bash benchmarks/cuda_session.sh keep", carry=[".gpu1"])
#            run(command="bash benchmarks/cuda_session.sh keep", carry=[".gpu2"])   ... one call per part
#   device:  run(command="bash benchmarks/cuda_session.sh install && bash benchmarks/cuda_session.sh tests")
#   device:  run(command="bash benchmarks/cuda_session.sh scaling wcsph") ... dfsph, pbf, memory
#
# .gitignore ignores /.gpu*/ (the parts, the joined wheels, the install) on both machines.
# Every stage writes its log and JSON under $OUT (what the tool brings back). Figures come only from
# those files: never type or estimate a GPU figure.
set -euo pipefail
cd "$(dirname "$0")/.."
PART_MB=${PART_MB:-44}
SITE=.gpusite

case "${1:-}" in
pack)  # here, with network: the run-time wheels for the device's Python 3.12, split into parts
    rm -rf .gpuwheels .gpu[0-9]*
    python3 -m pip download --quiet --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
        --platform manylinux2014_x86_64 -d .gpuwheels \
        "warp-lang==$(python3 -c 'import warp; print(warp.__version__)' 2>/dev/null || echo 1.19.0)" \
        usd-core meshio
    tar -C .gpuwheels -cf - . | split -b "${PART_MB}m" -d -a 1 - .gpupart
    i=1
    for p in .gpupart*; do mkdir -p ".gpu$i"; mv "$p" ".gpu$i/"; i=$((i + 1)); done
    rm -rf .gpuwheels
    ls -d .gpu[0-9]* | sed 's/^/carry: /'
    ;;
keep)  # there: nothing to do; the call only brings its carried part, which later calls keep
    ls -la .gpu[0-9]* 2>/dev/null || true
    ;;
install)  # there: join the parts, install the wheels and warp-sph into $SITE (no network, no build isolation)
    mkdir -p .gpuwheels && cat .gpu[0-9]*/.gpupart* | tar -C .gpuwheels -xf -
    python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --target "$SITE" .gpuwheels/*.whl
    PYTHONPATH=$PWD/$SITE python3 -m pip install -q --no-index --no-deps --no-build-isolation --target "$SITE" .
    PYTHONPATH=$PWD/$SITE PYTHONSAFEPATH=1 python3 -c 'import warp as wp, warp_sph; wp.init(); print("cuda devices:", wp.get_cuda_device_count(), [wp.get_device(f"cuda:{i}").name for i in range(wp.get_cuda_device_count())])'
    ;;
tests)  # there: the CUDA half of every device-fixture test, and tests/test_cuda_agreement.py
    # PYTHONSAFEPATH: the checkout's warp_sph/ (kernels/ lives beside it) must not shadow the installed package
    export PYTHONPATH=$PWD/$SITE PYTHONSAFEPATH=1
    python3 -m pytest -q -n 16 -k "cuda" tests 2>&1 | tee "${OUT:-/tmp}/tests_cuda.log" | tail -30
    ;;
scaling)  # there: bench scaling on cuda:0 for one solver, 6,859 to ~1.9M fluid particles (r = 0.025 ... 0.004 m)
    export PYTHONPATH=$PWD/$SITE PYTHONSAFEPATH=1
    solver=${2:-wcsph}
    python3 -m warp_sph.cli bench scaling --device cuda:0 --solver "$solver" \
        --radii "${RADII:-0.025,0.0125,0.00625,0.005,0.004}" --out "${OUT:-/tmp}/scaling_$solver" 2>&1 \
        | tee "${OUT:-/tmp}/scaling_$solver.log" | tail -20
    ;;
*)
    sed -n '2,17p' "$0"; exit 2
    ;;
esac
