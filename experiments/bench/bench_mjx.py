"""MJX suite tasks (``vsgjax/envs/mjx``): env steps per second against dm_control on the host.

For each task, MJX runs ``jit(scan(vmap(step)))`` over ``K`` agent steps for N = 1, 16 and 256
parallel envs (action repeat 2, the dmc preset, so one agent step is 2 env steps); the rate is
``N * K * action_repeat / seconds``, median over repeats, compilation excluded (reported
separately as ``first call``). dm_control's rate is one env in one process: the bare
``physics.step(n_sub_steps)`` (physics only) and ``env.step`` (physics, reward and
observation), random actions, no rendering, median over the same repeats.
Run: ``python -m experiments.bench.bench_mjx [--smoke] [task ...]``.
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import jax
import numpy as np

from experiments.bench.timing import median_times
from vsgjax.envs.mjx import make_mjx_task

RESULTS = Path(__file__).parent / "results" / "mjx.md"
TASKS = ("mjx_cartpole_swingup", "mjx_reacher_easy", "mjx_cheetah_run", "mjx_walker_walk",
         "mjx_hopper_stand")
NUM_ENVS = (1, 16, 256)
ACTION_REPEAT = 2
REPEATS, AGENT_STEPS = 5, 100
SMOKE = {"repeats": 1, "agent_steps": 3, "num_envs": (1, 16), "tasks": ("mjx_pendulum_swingup",)}


def mjx_rollout(task, num_envs: int, agent_steps: int):
    """A jitted function running ``agent_steps`` batched steps with random actions."""

    @jax.jit
    def rollout(state, key):
        def body(state, step_key):
            action = jax.random.uniform(step_key, (num_envs, task.action_dim), minval=-1.0,
                                        maxval=1.0)
            state = jax.vmap(task.step)(state, action)
            return state, state.reward
        return jax.lax.scan(body, state, jax.random.split(key, agent_steps))

    return rollout


def mjx_rate(name: str, num_envs: int, agent_steps: int, repeats: int) -> tuple[float, float]:
    """(env steps per second, seconds of the first call) for ``num_envs`` MJX envs."""
    task = make_mjx_task(name, action_repeat=ACTION_REPEAT, time_limit=10**9)
    keys = jax.random.split(jax.random.PRNGKey(0), num_envs)
    state = jax.block_until_ready(jax.jit(jax.vmap(task.reset))(keys))
    rollout = mjx_rollout(task, num_envs, agent_steps)
    start = time.perf_counter()
    jax.block_until_ready(rollout(state, jax.random.PRNGKey(1)))
    first = time.perf_counter() - start
    seconds = median_times(lambda: rollout(state, jax.random.PRNGKey(1)), repeats)[0]
    return num_envs * agent_steps * ACTION_REPEAT / seconds, first


def dm_control_rates(name: str, env_steps: int, repeats: int) -> tuple[float, float]:
    """(physics-only, full env.step) env steps per second of one dm_control env."""
    from dm_control import suite

    _, domain, task = name.split("_", 2)
    env = suite.load(domain, task, task_kwargs={"random": 0})
    spec = env.action_spec()
    rng = np.random.default_rng(0)
    controls = rng.uniform(spec.minimum, spec.maximum, (env_steps, *spec.shape))
    n_sub_steps = round(env.control_timestep() / env.physics.timestep())

    def env_run():
        env.reset()
        for control in controls:
            env.step(control)

    def physics_run():
        for control in controls:
            env.physics.set_control(control)
            env.physics.step(n_sub_steps)

    env_rate = env_steps / median_times(env_run, repeats)[0]
    env.reset()
    return env_steps / median_times(physics_run, repeats)[0], env_rate


def load_average() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg()) + f" ({os.cpu_count()} cores)"


def main(argv: list[str] | None = None) -> None:
    """Measure every task in ``argv`` (default ``TASKS``); ``--smoke`` runs a tiny check only."""
    argv = list(argv or [])
    smoke = "--smoke" in argv
    names = tuple(a for a in argv if a != "--smoke") or (SMOKE["tasks"] if smoke else TASKS)
    repeats = SMOKE["repeats"] if smoke else REPEATS
    agent_steps = SMOKE["agent_steps"] if smoke else AGENT_STEPS
    num_envs = SMOKE["num_envs"] if smoke else NUM_ENVS
    lines = ["## MJX suite tasks (`vsgjax/envs/mjx/`)", "",
             f"Env steps per second (physics control steps; action repeat {ACTION_REPEAT}), "
             f"median over {repeats} repeats of {agent_steps} agent steps, random actions, "
             "compilation excluded. MJX: `jit(scan(vmap(step)))` over N envs on "
             f"{jax.devices()[0].platform}; dm_control: one env on the host, bare "
             "`physics.step` and full `env.step` (reward and observation, no rendering). "
             f"Load average before: {load_average()}.", "",
             "| task | " + " | ".join(f"MJX N={n}" for n in num_envs)
             + " | dm_control physics | dm_control env | MJX first call (s, N=max) |",
             "|---|" + "---|" * (len(num_envs) + 3)]
    for name in names:
        rates = [mjx_rate(name, n, agent_steps, repeats) for n in num_envs]
        physics_rate, env_rate = dm_control_rates(name, agent_steps * ACTION_REPEAT, repeats)
        lines.append(f"| {name} | " + " | ".join(f"{r:,.0f}" for r, _ in rates)
                     + f" | {physics_rate:,.0f} | {env_rate:,.0f} | {rates[-1][1]:.1f} |")
        print(lines[-1], flush=True)
    lines += ["", f"Load average after: {load_average()}."]
    text = "\n".join(lines) + "\n"
    if not smoke:
        RESULTS.parent.mkdir(parents=True, exist_ok=True)
        RESULTS.write_text(text)
    print(text)


if __name__ == "__main__":
    main(sys.argv[1:])
