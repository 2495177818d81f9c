#!/bin/bash
# Every benchmark, one after the other (never two at once: they time each
# other), each one's output (stdout and stderr) saved to DIR/<name>.txt. About
# 20 minutes on 2 cores. Stops at the first benchmark that fails, with its exit
# code. bench_backends needs numba and bench_play Xvfb (Debian: apt-get install
# xvfb): both are checked before anything runs.
#
#     pip install -e ".[bench,fast,distributed,optimize,plot]"
#     sh benchmarks/run_all.sh [DIR]

# dash (/bin/sh on Debian) has no pipefail, without which a failing benchmark
# piped into tee would pass: run under bash whatever the caller ran us with
if [ -z "$BASH_VERSION" ]; then
    exec bash "$0" "$@"
fi
set -eo pipefail
out=${1:-benchmark-results}
here=$(dirname "$0")
export OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1
# stdout unbuffered: in the saved output an error comes after the lines printed before it, not first
export PYTHONUNBUFFERED=1

# what would otherwise fail minutes in, after the benchmarks before it
python - "$here" << 'EOF'
import sys

sys.path.insert(0, sys.argv[1])
from options import NUMBA_MISSING

from skfem_modal import _accel

_accel.AVAILABLE or sys.exit(f"run_all.sh: bench_backends needs numba: {NUMBA_MISSING}")
EOF
if ! command -v Xvfb > /dev/null; then
    echo "run_all.sh: bench_play needs Xvfb (Debian: apt-get install xvfb)" >&2
    exit 1
fi

mkdir -p "$out"
for bench in modal step backends contact iterations precompute blas_threads effects scaling optimize play render frames; do
    echo "== $bench"
    status=0
    python "$here/bench_$bench.py" 2>&1 | tee "$out/$bench.txt" || status=$?
    if [ "$status" -ne 0 ]; then
        echo "run_all.sh: bench_$bench failed (exit $status); its output is in $out/$bench.txt" >&2
        exit "$status"
    fi
done
