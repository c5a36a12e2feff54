"""DrQ-v2's update and acting costs (``vsgjax/agents/drqv2/agent.py``), and what a run of the
authors' length would take on this machine at that rate.

Per configuration: one jitted ``train_step`` on a batch of the windows the agent samples
(pixels: 84x84x3 frames, 3 stacked, n = 3; vectors: an MJX task's observation size), and one
jitted ``policy_step`` for one env. Medians over ``REPEATS`` calls after compilation (wall and
process CPU seconds). The projection counts updates only: a run of F frames with action
repeat R makes ``(F / R - prefill / R) / train_every`` updates (the authors' schedule);
stepping and rendering the envs, evaluation and logging come on top.
"""

from __future__ import annotations

import time
from pathlib import Path

import jax
import numpy as np

from experiments.bench.timing import median_times
from vsgjax.agents import make_agent
from vsgjax.config import make_config
from vsgjax.envs import EnvSpec

REPEATS = 5
RESULTS = Path(__file__).parent / "results" / "drqv2.md"
RUN_FRAMES = 1_000_000  # the VSG paper's DMC budget (env steps = frames)
# (label, task, size, observation spec, action dim)
CASES = (
    ("pixels, `paper`", "dmc_cheetah_run", "paper", {"image": (84, 84, 3)}, 6),
    ("pixels, `small`", "dmc_cheetah_run", "small", {"image": (84, 84, 3)}, 6),
    ("vectors, `cpu`", "mjx_cheetah_run", "cpu", {"vector": (17,)}, 6),
)


def window_batch(config, agent, spec: dict, action_dim: int, seed: int = 0) -> dict:
    """A batch of the agent's replay windows with random contents."""
    rng = np.random.default_rng(seed)
    shape = (config.train.batch, agent.replay.history + agent.replay.length)
    obs = {key: (rng.integers(0, 256, shape + dims, dtype=np.uint8) if key == "image"
                 else rng.normal(size=shape + dims).astype(np.float32))
           for key, dims in spec.items()}
    return {**obs, "action": rng.uniform(-1, 1, shape + (action_dim,)).astype(np.float32),
            "reward": rng.normal(size=shape).astype(np.float32),
            "is_first": np.zeros(shape, bool), "is_terminal": np.zeros(shape, bool)}


def bench_case(label: str, task: str, size: str, spec: dict, action_dim: int) -> dict:
    config = make_config(task, "drqv2", size)
    agent = make_agent(config, EnvSpec(spec, action_dim, False))
    key = jax.random.PRNGKey(0)
    state, batch = agent.init(key), window_batch(config, agent, spec, action_dim)
    started = time.perf_counter()
    jax.block_until_ready(agent.train_step(state, batch, key))
    compile_s = time.perf_counter() - started
    update = median_times(lambda: agent.train_step(state, batch, key), REPEATS)
    obs = {k: v[:1, -1] for k, v in batch.items() if k in spec}
    obs["is_first"] = np.ones(1, bool)
    params, carry = agent.acting_params(state), agent.initial_carry(1)
    agent.policy_step(params, carry, obs, key)
    act = median_times(lambda: agent.policy_step(params, carry, obs, key), REPEATS)
    train, repeat = config.train, config.env.action_repeat
    updates = (RUN_FRAMES // repeat - train.prefill // repeat) // train.train_every
    params_count = sum(x.size for x in jax.tree.leaves(state.params))
    return {"label": label, "batch": train.batch, "hidden": config.drq.hidden,
            "params": params_count, "update": update, "act": act, "compile": compile_s,
            "updates": updates, "hours": updates * update[0] / 3600}


def main() -> None:
    rows = [bench_case(*case) for case in CASES]
    lines = [
        "## DrQ-v2: update and acting time, and a 1M-frame run's updates",
        "",
        __doc__.strip().split("\n\n")[1].replace("\n", " "),
        "",
        "| configuration | batch | hidden | params | update s (wall / CPU) | act s | compile s "
        "| updates in 1M frames | hours of updates alone |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['label']} | {r['batch']} | {r['hidden']} | {r['params'] / 1e6:.2f}M "
            f"| {r['update'][0]:.3f} / {r['update'][1]:.3f} | {r['act'][0]:.4f} "
            f"| {r['compile']:.0f} | {r['updates']:,} | {r['hours']:.1f} |")
    RESULTS.parent.mkdir(exist_ok=True)
    RESULTS.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
