"""Agent update and acting costs (``vsgjax/agents/dreamer/agent.py``) at the ``small`` size
on BBS shapes.

Per model: the jitted world-model-only update (``vsgjax.agents.dreamer.api.world_model_step``)
against the agent's
joint update (world model + imagination actor-critic), so the behaviour-learning share is
visible, and one jitted ``policy_step`` for one env. Batch 16 x 50 of 64x64x3 images, horizon
15 (small size), 800 imagined start states. Medians over ``REPEATS`` calls after compilation;
compilation (lower + compile) is timed separately. CPU columns use the process's CPU time,
which is what the work costs when the machine is shared.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

from experiments.bench import timing
from vsgjax.agents import make_agent
from vsgjax.agents.dreamer import api
from vsgjax.config import make_config
from vsgjax.envs import EnvSpec

MODELS = ("vsg", "svsg", "dreamerv2")
REPEATS = 5
RESULTS = Path(__file__).parent / "results" / "agent.md"


def replay_batch(config, action_dim: int, seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    shape = (config.train.batch, config.train.length)
    is_first = np.zeros(shape, bool)
    is_first[:, 0] = True
    return {
        "image": rng.integers(0, 256, shape + (64, 64, 3), dtype=np.uint8),
        "action": rng.uniform(-1, 1, shape + (action_dim,)).astype(np.float32),
        "reward": rng.normal(size=shape).astype(np.float32),
        "is_first": is_first, "is_terminal": np.zeros(shape, bool),
    }


def compile_seconds(jitted, *args, **kwargs) -> float:
    started = time.perf_counter()
    jitted.lower(*args, **kwargs).compile()
    return time.perf_counter() - started


def median_times(fn, *args) -> tuple[float, float]:
    """Median (wall, process CPU) seconds of ``REPEATS`` calls of ``fn(*args)``, outputs ready."""
    return timing.median_times(lambda: fn(*args), REPEATS)


def bench_model(model: str) -> dict:
    config = make_config("bbs_basic", model, "small")
    agent, key = make_agent(config, EnvSpec((64, 64, 3), 2, False)), jax.random.PRNGKey(0)
    batch, state = replay_batch(config, 2), agent.init(key)
    wm_state = api.TrainState(state.params["wm"], state.opt["wm"], state.step)
    row = {"model": model,
           "wm_compile": compile_seconds(api.world_model_step, config, wm_state, batch, key),
           "agent_compile": compile_seconds(agent.train_step, agent, state, batch, key)}
    api.world_model_step(config, wm_state, batch, key)  # populate the call caches (compiled above)
    agent.train_step(state, batch, key)
    row["wm"] = median_times(lambda: api.world_model_step(config, wm_state, batch, key))
    row["agent"] = median_times(lambda: agent.train_step(state, batch, key))
    carry = agent.initial_carry(1)
    obs = {"image": batch["image"][:1, 0], "is_first": np.ones(1, bool)}
    policy = lambda: agent.policy_step(state.params, carry, obs, key)
    jax.block_until_ready(policy())
    row["policy"] = median_times(policy)
    return row


def markdown(rows: list[dict]) -> str:
    load = " ".join(f"{x:.1f}" for x in os.getloadavg())
    lines = [
        "## Agent update (`vsgjax/agents/dreamer/agent.py`, small size, BBS batch 16 x 50)",
        "",
        f"Median of {REPEATS} calls after compilation; wall / process-CPU seconds. `wm` is the "
        "world-model update alone (`api.world_model_step`), `agent` the joint update "
        "(world model + actor + critic over 800 start states x horizon 15). `policy` is one jitted "
        f"`policy_step` for one env. Load average at the end: {load} (2 cores, shared).",
        "",
        "| model | wm update s | agent update s | actor-critic share | policy ms "
        "| compile s (wm / agent) |",
        "|---|---|---|---|---|---|",
    ]
    for r in rows:
        share = 1.0 - r["wm"][1] / r["agent"][1]
        lines.append(
            f"| {r['model']} | {r['wm'][0]:.2f} / {r['wm'][1]:.2f} | "
            f"{r['agent'][0]:.2f} / {r['agent'][1]:.2f} | {100 * share:.0f}% (CPU) | "
            f"{1e3 * r['policy'][0]:.1f} / {1e3 * r['policy'][1]:.1f} | "
            f"{r['wm_compile']:.0f} / {r['agent_compile']:.0f} |")
    return "\n".join(lines) + "\n"


def main(models: tuple[str, ...] = MODELS) -> None:
    text = markdown([bench_model(model) for model in models])
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text)


if __name__ == "__main__":
    main(tuple(sys.argv[1:]) or MODELS)
