"""The paper-size figures on one GPU (``bash experiments/bench/gpu.sh``; a few minutes).

For S = 1 and 5 seeds in one process and float32 / bfloat16 matmuls (``model.precision``):

* one update alone: the trainer's vmapped ``DreamerAgent.train_step`` of S seeds at the
  ``paper`` size
  (BBS presets, batch 16 x 50), median of ``UPDATE_REPEATS`` after compilation, and the peak
  device memory JAX reports;
* the whole training loop (``bench_seeds.loop_child``): env steps and seed-updates per second,
  BBS with 250-step episodes and a 1000-step prefill so that the timed window starts soon.

Writes ``results/gpu.md``; it refuses to run where JAX sees no GPU (the CPU figures are in
``bench_seeds``). ``python -m experiments.bench.gpu_paper debug`` runs the same at the debug
size anywhere and prints the table without writing it (a check of the script).
"""

from __future__ import annotations

import statistics
import sys
import time
from pathlib import Path

COMBOS = ((1, "float32"), (1, "bfloat16"), (5, "float32"), (5, "bfloat16"))
UPDATE_REPEATS = 10
WINDOW, REPEATS = 20, 2
RESULTS = Path(__file__).parent / "results" / "gpu.md"


def time_update(seeds: int, precision: str, size: str) -> tuple[float, int | None]:
    """Median seconds of one S-seed update at the paper size, and the device's peak bytes."""
    import jax
    import numpy as np

    from experiments.bench.bench_agent import replay_batch
    from vsgjax.agents import make_agent
    from vsgjax.config import make_config
    from vsgjax.envs import EnvSpec
    from vsgjax.loop.parallel import Parallel, stack

    config = make_config("bbs_basic", "vsg", size, [f"model.precision={precision}",
                                                    "train.batch=16", "train.length=50"])
    agent = make_agent(config, EnvSpec((64, 64, 3), 2, False))
    parallel = Parallel(agent, seeds, 1)
    state = parallel.put_state(stack([agent.init(jax.random.PRNGKey(s)) for s in range(seeds)]))
    batch = parallel.put_batch([replay_batch(config, 2)] * seeds)
    keys = np.stack([jax.random.PRNGKey(s) for s in range(seeds)])
    times = []
    for _ in range(UPDATE_REPEATS + 1):  # the first call compiles
        started = time.perf_counter()
        state, metrics = parallel.train_step(state, batch, keys)
        jax.block_until_ready(metrics)
        times.append(time.perf_counter() - started)
    stats = jax.devices()[0].memory_stats() or {}
    return statistics.median(times[1:]), stats.get("peak_bytes_in_use")


def main(size: str = "paper") -> None:
    import jax

    from experiments.bench.bench_seeds import loop_child, summary
    from experiments.bench.run_all import stamp_new_sections

    if size == "paper" and jax.devices()[0].platform != "gpu":
        sys.exit(f"gpu_paper: JAX sees no GPU ({jax.devices()}); install the cuda extra")
    started = time.time()
    lines = [f"## {size.capitalize()} size on one GPU (VSG, BringBackShapes)", "",
             f"Update: median of {UPDATE_REPEATS} S-seed updates (16 x 50 per seed) after "
             f"compilation. Loop: {WINDOW} agent steps per seed per window, median of {REPEATS}, "
             "at the preset's train ratio.", "",
             "| S | precision | update s | per seed s | peak device GiB | loop env steps/s "
             "| loop seed-updates/s | collection % |", "|---|---|---|---|---|---|---|---|"]
    for seeds, precision in COMBOS:
        update, peak = time_update(seeds, precision, size)
        loop = summary([loop_child(list(range(seeds)), WINDOW, REPEATS, size=size,
                                   overrides=("train.prefill=1000",
                                              f"model.precision={precision}"))])
        peak_text = f"{peak / 2**30:.1f}" if peak else "n/a"
        lines.append(f"| {seeds} | {precision} | {update:.3f} | {update / seeds:.3f} | "
                     f"{peak_text} | {loop['env_steps_per_s']:.1f} | "
                     f"{loop['updates_per_s']:.2f} | {100 * loop['collect_share']:.1f} |")
        print(lines[-1], flush=True)
    text = "\n".join(lines) + "\n"
    if size == "paper":
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(text)
        stamp_new_sections(started)
    print(text)


if __name__ == "__main__":
    main(*sys.argv[1:2])
