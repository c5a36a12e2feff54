"""Latent dynamics alone: jitted ``observe`` over a batch and ``imagine`` from many start states.

``observe``: B=16 sequences of T=50 steps (vmapped), forward only, random embeddings.
``imagine``: 800 start states (vmapped), horizon 15, a linear tanh policy on the features.
Median over several runs after compilation (reported separately); FLOPs counted from the jaxpr
(scan bodies once per step, matmuls only) by :mod:`experiments.bench.flops`.

Run ``python -m experiments.bench.bench_core_dyn [size]`` (size: small (default) or paper).
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from experiments.bench.flops import count_flops
from vsgjax.agents.dreamer.dynamics import make_dynamics
from vsgjax.agents.dreamer.networks import embed_dim
from vsgjax.config import make_config

MODELS = ("dreamerv2", "vsg", "svsg")
BATCH, LENGTH, STARTS, HORIZON, ACTIONS, RUNS = 16, 50, 800, 15, 2, 7
RESULTS = Path(__file__).parent / "results" / "core_dyn.md"


def _timed(fn, *args) -> tuple[float, float, float]:
    """(compile s, median wall ms, median CPU ms) of a jitted ``fn``."""
    start = time.perf_counter()
    compiled = jax.jit(fn).lower(*args).compile()
    compile_s = time.perf_counter() - start
    walls, cpus = [], []
    for _ in range(RUNS):
        wall, cpu = time.perf_counter(), time.process_time()
        jax.block_until_ready(compiled(*args))
        walls.append(1e3 * (time.perf_counter() - wall))
        cpus.append(1e3 * (time.process_time() - cpu))
    return compile_s, statistics.median(walls), statistics.median(cpus)


def _bench_model(name: str, size: str) -> list[str]:
    config = make_config("bbs_basic", name, size)
    dyn = make_dynamics(config.model, name, config.precision)
    embed = embed_dim(config.wm.cnn_depth)
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    params = dyn.init(keys[0], embed, ACTIONS)
    embeds = jax.random.normal(keys[1], (BATCH, LENGTH, embed))
    actions = jnp.zeros((BATCH, LENGTH, ACTIONS))
    is_first = jnp.zeros((BATCH, LENGTH), bool).at[:, 0].set(True)
    seq_keys = jax.random.split(keys[2], BATCH)
    observe = jax.vmap(dyn.observe, in_axes=(None, 0, 0, 0, 0))
    weights = jnp.zeros((dyn.feat_dim, ACTIONS))

    def imagine(params, starts, keys):
        policy = lambda feat, key: jnp.tanh(feat @ weights)
        return jax.vmap(dyn.imagine, in_axes=(None, None, 0, None, 0))(
            params, policy, starts, HORIZON, keys)

    starts = jax.tree.map(lambda x: jnp.broadcast_to(x, (STARTS, *x.shape)), dyn.initial())
    start_keys = jax.random.split(keys[3], STARTS)
    rows = []
    for label, fn, args, steps in (
        (f"observe {BATCH}x{LENGTH}", observe, (params, embeds, actions, is_first, seq_keys),
         BATCH * LENGTH),
        (f"imagine {STARTS}x{HORIZON}", imagine, (params, starts, start_keys), STARTS * HORIZON),
    ):
        compile_s, wall_ms, cpu_ms = _timed(fn, *args)
        gflops = count_flops(fn, *args) / 1e9
        rows.append(
            f"| {name} | {label} | {compile_s:.1f} | {wall_ms:.1f} ({cpu_ms:.1f}) | "
            f"{steps / wall_ms * 1e3:,.0f} | {gflops:.2f} | {gflops / wall_ms * 1e3:.1f} |"
        )
    return rows


def main(size: str = "small") -> str:
    lines = [
        "## Latent dynamics (observe / imagine)",
        "",
        f"Size `{size}` (BBS presets), forward only, random inputs; median of {RUNS} runs after "
        "compilation. Wall ms (CPU ms of this process). Throughput in latent steps per second "
        "(sequences x length, or start states x horizon); GFLOP from the jaxpr (matmuls).",
        "",
        "| model | call | compile s | ms | steps/s | GFLOP | GFLOP/s |",
        "|---|---|---|---|---|---|---|",
    ]
    for name in MODELS:
        lines += _bench_model(name, size)
    text = "\n".join(lines) + "\n"
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text)
    return text


if __name__ == "__main__":
    main(*sys.argv[1:])
