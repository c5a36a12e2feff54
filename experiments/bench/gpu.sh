#!/usr/bin/env bash
# The paper-size benchmark on one GPU (S = 1 and 5 seeds, float32 and bfloat16), a few minutes:
#     bash experiments/bench/gpu.sh
# Needs the cuda extra (pip install -e ".[cuda]"); writes experiments/bench/results/gpu.md and
# reassembles BENCHMARKS.md. The CPU sections are left as they are.
set -euo pipefail
cd "$(dirname "$0")/../.."
PY=${PY:-.venv/bin/python}
"$PY" -c 'import jax, sys; sys.exit(jax.devices()[0].platform != "gpu")' || {
    echo "gpu.sh: JAX sees no GPU here; install the cuda extra on a GPU machine" >&2; exit 2; }
MUJOCO_GL=egl "$PY" -m experiments.bench.gpu_paper
"$PY" -m experiments.bench.run_all --assemble
