"""How to spend 2 CPU cores on `cpu`-size MJX runs: one process, two, or seeds spread on devices.

The `cpu_proprio` experiment's cost is the device loop's training calls (each one episode of
every env with its 250 updates). This times one training call of VSG at the ``cpu`` size on
``mjx_cartpole_swingup`` in each way of running seeds on this machine, every process started
with the allocator the launcher uses (:mod:`vsgjax.allocator`):

* one process, one seed (nothing else running);
* two single-seed processes side by side (``launch --jobs 2``; their calls timed together after
  both warmed up);
* one process, two seeds vmapped on one device (``--seeds 0,1``);
* one process, S seeds spread over S host devices
  (``XLA_FLAGS=--xla_force_host_platform_device_count=S``, ``train.devices=S``): each device
  runs its seeds' part of the program on its own thread.

Each process warms up (prefill, compilation, its first training call), waits at a barrier, then
times ``repeats`` calls; medians. Evaluation, checkpoints and videos are off. Minutes per run:
the training calls of a 100k-env-step run (after the prefill) at the measured rate,
divided by the seeds that share them (the issue's accounting: S seeds in one process are S runs),
without evaluation, prefill and compilation (the committed runs' own clocks have the totals).

    python -m experiments.bench.bench_mjx_cores [--repeats 2] [--smoke]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TASK, MODEL = "mjx_cartpole_swingup", "vsg"
OFF = ["train.eval_every=1000000000", "train.video_every=1000000000",
       "train.ckpt_every=1000000000", "train.steps=1000000000"]
SMOKE = ["env.time_limit=40", "train.length=8", "train.batch=3", "train.train_every=5",
         "train.prefill=80", "train.pretrain=1"]
RUN_STEPS = 100_000  # env steps of one cpu_proprio run
RESULTS = Path(__file__).parent / "results" / "mjx_cores.md"
# (label, processes, seeds per process, forced host devices per process)
WAYS = (("one process, 1 seed", 1, 1, 1),
        ("two processes side by side, 1 seed each", 2, 1, 1),
        ("one process, 2 seeds on 1 device", 1, 2, 1),
        ("one process, 2 seeds on 2 host devices", 1, 2, 2),
        ("one process, 3 seeds on 3 host devices", 1, 3, 3))


# --- in a child process --------------------------------------------------------------------------

def child(seeds: int, devices: int, repeats: int, barrier: str, size: str,
          overrides: list[str]) -> dict:
    """Warm up a device-loop trainer of ``seeds`` seeds, wait at the barrier, time calls."""
    import jax

    from experiments.bench.bench_mjx_loop import warm
    from experiments.bench.bench_seeds import wait_at
    from vsgjax.config import make_config
    from vsgjax.train import enable_compilation_cache, make_trainer

    enable_compilation_cache()
    configs = [make_config(TASK, MODEL, size, [f"train.seed={seed}", f"train.devices={devices}",
                                               *OFF, *overrides]) for seed in range(seeds)]
    with tempfile.TemporaryDirectory() as root:
        started = time.perf_counter()
        trainer = make_trainer(configs, [Path(root) / f"s{seed}" for seed in range(seeds)],
                               progress=False)
        try:
            while not warm(trainer, "device"):
                trainer.iteration()
            jax.block_until_ready(trainer.state)
            warmup = time.perf_counter() - started
            wait_at(Path(barrier), os.getpid())
            calls = []
            for _ in range(repeats):
                started = time.perf_counter()
                trainer.iteration()
                jax.block_until_ready(trainer.state)
                calls.append(time.perf_counter() - started)
            env_steps = (configs[0].env.num_envs * trainer.program.episode_steps
                         * configs[0].env.action_repeat)
        finally:
            trainer.close()
    return {"call_s": statistics.median(calls), "warmup_s": warmup, "seeds": seeds,
            "env_steps_per_call": env_steps,
            "updates_per_call": trainer.program.updates_per_episode,
            "prefill": configs[0].train.prefill}


# --- in the parent -------------------------------------------------------------------------------

def run_way(processes: int, seeds: int, devices: int, repeats: int, size: str,
            overrides: list[str]) -> list[dict]:
    """Start ``processes`` children together; each returns its median call."""
    from vsgjax.allocator import allocator_env

    env = dict(os.environ, JAX_PLATFORMS="cpu", **allocator_env())
    if devices > 1:
        env["XLA_FLAGS"] = f"--xla_force_host_platform_device_count={devices}"
    with tempfile.TemporaryDirectory() as barrier:
        spec = json.dumps({"seeds": seeds, "devices": devices, "repeats": repeats,
                           "barrier": barrier, "size": size, "overrides": overrides})
        children = [subprocess.Popen([sys.executable, "-m", "experiments.bench.bench_mjx_cores",
                                      "--child", spec], stdout=subprocess.PIPE, text=True,
                                     env=env) for _ in range(processes)]
        while len(list(Path(barrier).glob("ready-*"))) < processes:
            if any(child.poll() not in (None, 0) for child in children):
                break
            time.sleep(0.2)
        (Path(barrier) / "go").touch()
        results = []
        for process in children:
            out, _ = process.communicate()
            if process.returncode:
                raise RuntimeError(f"bench child failed ({process.returncode}): {out[-2000:]}")
            results.append(json.loads(out.strip().splitlines()[-1]))
    return results


def row(label: str, results: list[dict]) -> dict:
    first = results[0]
    calls = math.ceil((RUN_STEPS - first["prefill"]) / first["env_steps_per_call"])
    seed_calls_per_s = sum(r["seeds"] / r["call_s"] for r in results)
    per_process_s = statistics.median(r["call_s"] for r in results)
    return {"label": label, "call_s": per_process_s, "seeds": first["seeds"],
            "processes": len(results), "calls": calls,
            "env_steps_per_call": first["env_steps_per_call"],
            "updates_per_call": first["updates_per_call"],
            "env_steps_per_s": seed_calls_per_s * first["env_steps_per_call"],
            "updates_per_s": seed_calls_per_s * first["updates_per_call"],
            "run_wall_min": calls * per_process_s / 60,
            "min_per_run": calls / seed_calls_per_s / 60,
            "warmup_s": max(r["warmup_s"] for r in results)}


def markdown(rows: list[dict], repeats: int) -> str:
    base, first = rows[0]["updates_per_s"], rows[0]
    lines = ["## MJX device loop at `cpu`: one process, two, or seeds spread on host devices",
             "",
             f"VSG at the `cpu` size on {TASK}: one training call ("
             f"{first['env_steps_per_call']:,} env steps and {first['updates_per_call']} "
             f"updates per seed), median of {repeats} calls after warm-up, every process on "
             "mimalloc as the launcher starts it. Rates are totals over all seeds of all "
             f"processes. *Run wall min*: {first['calls']} calls (a {RUN_STEPS:,}-env-step run "
             "after prefill) at the process's call time; *min per run*: the same divided by the "
             "seeds that share the machine's time (S seeds in one process count as S runs). "
             "Evaluation, prefill and compilation are not included.",
             "",
             "| way | processes x seeds | call s | env steps/s | seed-updates/s | vs one seed "
             "| run wall min | min per run | warm-up s |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['label']} | {r['processes']} x {r['seeds']} | {r['call_s']:.1f} "
                     f"| {r['env_steps_per_s']:.1f} | {r['updates_per_s']:.2f} "
                     f"| {r['updates_per_s'] / base:.2f}x | {r['run_wall_min']:.1f} "
                     f"| {r['min_per_run']:.1f} | {r['warmup_s']:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m experiments.bench.bench_mjx_cores",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--smoke", action="store_true",
                        help="debug size, 40-step episodes, one call per way; writes nothing")
    args = parser.parse_args(argv or [])
    size, overrides = ("debug", SMOKE) if args.smoke else ("cpu", [])
    repeats = 1 if args.smoke else args.repeats
    rows = []
    for label, processes, seeds, devices in WAYS:
        rows.append(row(label, run_way(processes, seeds, devices, repeats, size, overrides)))
        print(rows[-1], flush=True)
    text = markdown(rows, repeats)
    print(text)
    if not args.smoke:
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(text)


if __name__ == "__main__":
    if len(sys.argv) > 2 and sys.argv[1] == "--child":
        print(json.dumps(child(**json.loads(sys.argv[2]))))
    else:
        main(sys.argv[1:])
