"""DreamerPro's and VSGPro's update cost beside DreamerV2's (``vsgjax/agents/dreamer/agent.py``),
each at its own DMC preset, at the ``small`` and ``paper`` sizes.

Per model and size: one jitted ``train_step`` (world model, actor and critic) on a replay batch
of the preset's shape (64x64x3 images; DreamerPro and VSGPro train on two shifted views of it, so
their world model and actor-critic see twice the sequences), median of ``REPEATS`` calls after
compilation, wall and process-CPU seconds. A second table times the prototype losses alone
(``prototypes.prototype_losses`` with its gradient) on the batch's shapes, to show what the
prototypes add. The paper's batch (50 x 51 doubled) is what the authors train on a GPU; on a CPU
it says how far from practical a pixel run is here.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

from experiments.bench.timing import median_times
from vsgjax.agents import make_agent
from vsgjax.agents.dreamer.representation import prototype_losses as prototypes
from vsgjax.config import make_config
from vsgjax.envs import EnvSpec

MODELS = ("dreamerv2", "dreamerpro", "vsgpro")
SIZES = ("small", "paper")
TASK, ACTIONS = "dmc_walker_run", 6
REPEATS = 3
RESULTS = Path(__file__).parent / "results" / "dreamerpro.md"


def replay_batch(config, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    shape = (config.train.batch, config.train.length)
    is_first = np.zeros(shape, bool)
    is_first[:, 0] = True
    return {"image": rng.integers(0, 256, shape + (64, 64, 3), dtype=np.uint8),
            "action": rng.uniform(-1, 1, shape + (ACTIONS,)).astype(np.float32),
            "reward": rng.normal(size=shape).astype(np.float32),
            "is_first": is_first, "is_terminal": np.zeros(shape, bool)}


def bench_update(model: str, size: str) -> dict:
    config = make_config(TASK, model, size)
    agent, key = make_agent(config, EnvSpec((64, 64, 3), ACTIONS, False)), jax.random.PRNGKey(0)
    batch, state = replay_batch(config), agent.init(key)
    started = time.perf_counter()
    jax.block_until_ready(agent.train_step(state, batch, key))
    first = time.perf_counter() - started
    update = median_times(lambda: agent.train_step(state, batch, key), REPEATS)
    return {"model": model, "size": size, "batch": (config.train.batch, config.train.length),
            "first": first, "update": update}


def bench_losses(size: str) -> dict:
    """The prototype losses and their gradient alone, on the doubled batch of ``size``."""
    config = make_config(TASK, "dreamerpro", size)
    proto, train = config.proto, config.train
    shape = (2 * train.batch, train.length, proto.dim)
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    protos = prototypes.l2_normalize(jax.random.normal(keys[0], (proto.prototypes, proto.dim)))
    obs, feat = (jax.random.normal(k, shape) for k in keys[1:3])
    ema = prototypes.l2_normalize(jax.random.normal(keys[3], shape))

    def total(p, o, f):
        losses = prototypes.prototype_losses(
            p, o, f, ema, temperature=proto.temperature, sinkhorn_eps=proto.sinkhorn_eps,
            sinkhorn_iters=proto.sinkhorn_iters, warm_up=proto.warm_up)
        return sum(losses.values())

    grad = jax.jit(jax.grad(total, argnums=(0, 1, 2)))
    jax.block_until_ready(grad(protos, obs, feat))
    return {"size": size, "shape": shape,
            "time": median_times(lambda: grad(protos, obs, feat), REPEATS)}


def markdown(updates: list[dict], losses: list[dict]) -> str:
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    lines = [
        "## DreamerPro and VSGPro update beside DreamerV2's (`dmc` presets, 64x64 pixels)",
        "",
        f"Median of {REPEATS} jitted `train_step` calls after compilation (wall / process-CPU "
        "seconds); `first` is the first call with its compilation. Each model at its own DMC "
        "preset: DreamerV2 the VSG release's (deter 1024, 32x32 categorical, CNN depth 32), "
        "DreamerPro and VSGPro the authors' (deter 200, 32 Gaussian, CNN depth 48, two views "
        f"of the batch). Load average at the end: {load} (2 cores, shared).",
        "",
        "| model | size | batch (B x T) | update s (wall / CPU) | first call s |",
        "|---|---|---|---|---|",
    ]
    for r in updates:
        wall, cpu = r["update"]
        lines.append(f"| {r['model']} | `{r['size']}` | {r['batch'][0]} x {r['batch'][1]} | "
                     f"{wall:.2f} / {cpu:.2f} | {r['first']:.0f} |")
    lines += ["", "The prototype losses alone (2,500 prototypes of 32, Sinkhorn per view) with "
              "their gradient, on the doubled batch's projections:", "",
              "| size | projections | losses + gradient ms (wall / CPU) |", "|---|---|---|"]
    for r in losses:
        wall, cpu = r["time"]
        lines.append(f"| `{r['size']}` | {' x '.join(map(str, r['shape']))} | "
                     f"{1e3 * wall:.0f} / {1e3 * cpu:.0f} |")
    return "\n".join(lines) + "\n"


def main(sizes: tuple[str, ...] = SIZES) -> None:
    updates = [bench_update(model, size) for size in sizes for model in MODELS]
    losses = [bench_losses(size) for size in sizes]
    text = markdown(updates, losses)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text)


if __name__ == "__main__":
    main(tuple(sys.argv[1:]) or SIZES)
