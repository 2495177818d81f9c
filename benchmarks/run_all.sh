#!/bin/sh
# Every benchmark, one after the other (never two at once: they time each
# other), each one's output saved to DIR/<name>.txt. About 20 minutes on 2 cores.
# bench_play needs Xvfb (Debian: apt-get install xvfb).
#
#     pip install -e ".[bench,fast,distributed,optimize,plot]"
#     sh benchmarks/run_all.sh [DIR]
set -e
out=${1:-benchmark-results}
mkdir -p "$out"
here=$(dirname "$0")
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
for bench in modal step backends contact iterations precompute blas_threads effects scaling optimize play render frames; do
    echo "== $bench"
    python "$here/bench_$bench.py" | tee "$out/$bench.txt"
done
