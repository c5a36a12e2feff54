"""The whole agent update (world model + imagination + actor + critic): useful GFLOP per update
and the rate it reaches, as a fraction of a large float32 matmul's rate measured in the same
process, at the ``cpu``, ``small`` and ``paper`` sizes (VSG)::

    python -m experiments.bench.bench_agent_update [--sizes cpu small paper] [--smoke]

``cpu`` trains on an MJX task's vector observations (``mjx_cartpole_swingup``, its own batch of
``train.batch`` x ``train.length``), ``small`` and ``paper`` on BringBackShapes' 64x64 images
at their own batch. FLOPs are counted from the jaxpr (:mod:`experiments.bench.flops`:
matmuls and convolutions as the lax convolutions they equal, scan bodies times their length).
Each size runs in its own subprocess; medians over ``--updates`` updates after compilation.
The profile of the ``cpu`` update: its world-model gradient and its actor gradient (the
imagination from every posterior state and the backward pass through it) timed alone, and the
whole update with XLA:CPU on one thread (``ONE_THREAD``) against its default thread pool.
``--smoke`` runs the ``cpu`` size for 2 updates and writes nothing.
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np

from experiments.bench.bench_world_model import matmul_rate, model_flops
from experiments.bench.run_all import machine_line
from vsgjax.agents import make_agent
from vsgjax.agents.dreamer import behaviour as bhv
from vsgjax.config import make_config
from vsgjax.envs import EnvSpec
from vsgjax.envs.mjx import make_mjx_task

RESULTS = Path(__file__).parent / "results" / "agent_update.md"
SIZES = ("cpu", "small", "paper")
TASKS = {"cpu": "mjx_cartpole_swingup", "small": "bbs_basic", "paper": "bbs_basic"}
MODEL = "vsg"
ONE_THREAD = "--xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"


def _batch(config, obs: dict, action_dim: int) -> dict:
    rng = np.random.default_rng(0)
    shape = (config.train.batch, config.train.length)
    is_first = np.zeros(shape, bool)
    is_first[:, 0] = True
    batch = {"action": rng.uniform(-1, 1, shape + (action_dim,)).astype(np.float32),
             "reward": rng.normal(size=shape).astype(np.float32),
             "is_first": is_first, "is_terminal": np.zeros(shape, bool)}
    for key, item_shape in obs.items():
        if key == "image":
            batch[key] = rng.integers(0, 256, shape + tuple(item_shape), dtype=np.uint8)
        else:
            batch[key] = rng.normal(size=shape + tuple(item_shape)).astype(np.float32)
    return batch


def agent_and_batch(size: str) -> tuple[object, dict]:
    config = make_config(TASKS[size], MODEL, size)
    if size == "cpu":
        task = make_mjx_task(config.env.task, config.env.action_repeat, config.env.time_limit)
        obs = {"vector": (sum(s[0] for s, _ in task.observation_spec().values()),)}
        action_dim = task.action_dim
    else:
        obs, action_dim = {"image": (64, 64, 3)}, 2
    return make_agent(config, EnvSpec(obs, action_dim, False)), _batch(config, obs, action_dim)


def median_seconds(fn, *args, repeats: int) -> float:
    jax.block_until_ready(fn(*args))
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        jax.block_until_ready(fn(*args))
        times.append(time.perf_counter() - started)
    return statistics.median(times)


def measure(size: str, updates: int) -> dict:
    """One size's agent update: useful FLOPs, median seconds, and the matmul rate (subprocess)."""
    agent, batch = agent_and_batch(size)
    config = agent.config
    state, key = agent.init(jax.random.PRNGKey(0)), jax.random.PRNGKey(1)
    started = time.perf_counter()
    compiled = agent.train_step.lower(agent, state, batch, key).compile()
    compile_s = time.perf_counter() - started
    flops = model_flops(lambda s, b, k: agent.train_step.__wrapped__(agent, s, b, k),
                        state, batch, key)
    times = []
    for i in range(updates):
        started = time.perf_counter()
        jax.block_until_ready(compiled(state, batch, jax.random.PRNGKey(i)))
        times.append(time.perf_counter() - started)
    rate = matmul_rate()
    update_s = statistics.median(times)
    return {"size": size, "task": TASKS[size], "batch": config.train.batch,
            "length": config.train.length, "horizon": config.ac.horizon,
            "deter": config.model.deter, "params": sum(x.size for x in
                                                       jax.tree.leaves(state.params)),
            "useful_gflop": flops["useful"] / 1e9, "update_s": update_s,
            "gflops": flops["useful"] / 1e9 / update_s, "matmul_gflops": rate / 1e9,
            "fraction": flops["useful"] / update_s / rate, "compile_s": compile_s,
            "updates": updates}


def measure_parts(updates: int) -> dict:
    """The cpu update's world-model gradient, actor gradient and whole update, each timed
    alone (seconds, median)."""
    agent, batch = agent_and_batch("cpu")
    state, key = agent.init(jax.random.PRNGKey(0)), jax.random.PRNGKey(1)
    params, wm = state.params, agent.world_model
    _, (_, posts) = jax.jit(wm.loss)(params["wm"], batch, key)
    starts, start_continue = bhv.start_states(posts, batch["is_terminal"], agent.behaviour,
                                              drop_last=agent.config.wm.discount_head)
    keys = jax.random.split(key, start_continue.shape[0])

    def actor_grad(actor):
        return jax.grad(lambda a: bhv.actor_loss(
            a, agent.behaviour, params["critic"], params["slow_critic"],
            agent.world_fns(params["wm"]), starts, start_continue, keys)[0])(actor)

    wm_grad = jax.jit(jax.grad(lambda p: wm.loss(p, batch, key)[0]))
    return {"update_s": median_seconds(agent.train_step, state, batch, key, repeats=updates),
            "wm_grad_s": median_seconds(wm_grad, params["wm"], repeats=updates),
            "actor_grad_s": median_seconds(jax.jit(actor_grad), params["actor"],
                                           repeats=updates)}


def _child(mode: str, updates: int, xla_flags: str = "") -> dict:
    env = {**os.environ, "XLA_FLAGS": xla_flags} if xla_flags else None
    output = subprocess.run(
        [sys.executable, "-m", "experiments.bench.bench_agent_update", "--child", mode,
         "--updates", str(updates)], check=True, capture_output=True, text=True,
        env=env).stdout
    return json.loads(output.strip().splitlines()[-1])


def markdown(rows: list[dict]) -> str:
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    lines = ["## Whole agent update (VSG): useful GFLOP and the matmul rate", "",
             f"_Measured {datetime.date.today().isoformat()} on {machine_line()}; load "
             f"average at the end {load}._", "",
             "One jitted agent update (world model, imagination from every posterior state, "
             "actor, critic) at each size's own batch; median of the updates after "
             "compilation. The matmul rate is a 2048^2 float32 matmul in the same process.", "",
             "| size | task (observation) | batch x length, horizon | deter | params | useful "
             "GFLOP / update | update s | GFLOP/s | matmul GFLOP/s | fraction | compile s |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| `{r['size']}` | {r['task']} | {r['batch']} x {r['length']}, {r['horizon']} | "
            f"{r['deter']} | {r['params'] / 1e6:.2f}M | {r['useful_gflop']:.2f} | "
            f"{r['update_s']:.3f} | {r['gflops']:.1f} | {r['matmul_gflops']:.0f} | "
            f"{100 * r['fraction']:.1f}% | {r['compile_s']:.0f} |")
    return "\n".join(lines) + "\n"


def profile_markdown(parts: dict, one_thread: dict) -> str:
    whole = parts["update_s"]
    return "\n".join([
        "### Profile of the `cpu` update", "",
        "| part (timed alone) | seconds | share of the update |", "|---|---|---|",
        f"| world-model gradient | {parts['wm_grad_s']:.3f} | "
        f"{100 * parts['wm_grad_s'] / whole:.0f}% |",
        f"| actor gradient (imagination and its backward pass) | {parts['actor_grad_s']:.3f} | "
        f"{100 * parts['actor_grad_s'] / whole:.0f}% |",
        f"| whole update | {whole:.3f} | 100% |",
        f"| whole update, XLA:CPU on one thread | {one_thread['update_s']:.3f} | "
        f"{one_thread['update_s'] / whole:.2f}x the default |", ""])


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.bench.bench_agent_update",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", nargs="+", default=list(SIZES), choices=SIZES)
    parser.add_argument("--updates", type=int, default=5)
    parser.add_argument("--smoke", action="store_true")
    parser.add_argument("--child", choices=(*SIZES, "parts"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv or [])
    if args.child:
        result = (measure_parts(args.updates) if args.child == "parts"
                  else measure(args.child, args.updates))
        print(json.dumps(result))
        return
    if args.smoke:
        print(markdown([_child("cpu", 2)]))
        return
    text = markdown([_child(size, args.updates) for size in args.sizes])
    if "cpu" in args.sizes:
        text += "\n" + profile_markdown(_child("parts", args.updates),
                                        _child("parts", args.updates, ONE_THREAD))
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text)


if __name__ == "__main__":
    main(sys.argv[1:])
