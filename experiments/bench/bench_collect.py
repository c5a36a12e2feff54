"""Collection benchmark: bare env step rates and the cost of the host boundary per agent step.

For each (env, N envs, driver) we time, per agent step (median over repeats, compilation
excluded and reported separately):

* ``collect``: :meth:`vsgjax.data.collect.Collector.run` over a chunk;
* ``env``: :meth:`vsgjax.data.collect.EnvBatch.step` alone in a Python loop (same envs, same
  recording), with precomputed actions;
* ``policy``: the policy alone, ``jax.lax.scan`` over the chunk on a fixed observation;
* ``boundary = collect - env - policy``: what crossing between JAX and Python costs.

Policies: a small recurrent stand-in for the agent (pooled image -> dense -> GRU-like update ->
tanh action, state reset on ``is_first``), so the boundary, not the network, dominates; and the
real agent's ``policy_step`` at the ``small`` size (VSG, 61 parameter arrays), at the training
loop's chunk of 5 steps and at 50.
Run: ``python -m experiments.bench.bench_collect``.
"""

from __future__ import annotations

import functools
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from experiments.bench.timing import median_times
from tests.support.fake_envs import FakeImageEnv
from vsgjax.config import make_config
from vsgjax.data.collect import DEFAULT_CHUNK, Collector, EnvBatch, make_env_batch
from vsgjax.envs import make_env
from vsgjax.envs.wrappers import DefaultSeed

RESULTS = Path(__file__).parent / "results" / "collect.md"
HIDDEN = 256
REPEATS = 15
KEY = jax.random.PRNGKey(0)
TRAIN_CHUNK = 5  # the training loop's chunk: train_every agent steps


def fake_env(seed: int):
    return DefaultSeed(FakeImageEnv(length=200, action_dim=2), seed)


def fake_batch(num_envs: int) -> EnvBatch:
    return EnvBatch([functools.partial(fake_env, i) for i in range(num_envs)])


def standin_policy(params, carry, obs, key):
    """Pooled image -> dense -> gated recurrent update -> tanh action with Gaussian noise."""
    image = obs["image"].astype(jnp.float32) / 255.0 - 0.5
    n, h, w, c = image.shape
    pooled = image.reshape(n, 8, h // 8, 8, w // 8, c).mean((2, 4)).reshape(n, -1)
    carry = jnp.where(obs["is_first"][:, None], 0.0, carry)
    x = jax.nn.elu(pooled @ params["embed"])
    gate = jax.nn.sigmoid(jnp.concatenate([x, carry], -1) @ params["gate"])
    carry = gate * jnp.tanh(x + carry @ params["recur"]) + (1 - gate) * carry
    mean = jnp.tanh(carry @ params["out"])
    return carry, jnp.clip(mean + 0.3 * jax.random.normal(key, mean.shape), -1.0, 1.0)


def standin_params(obs_shape, action_dim, key):
    in_dim = 64 * obs_shape[-1]
    shapes = {"embed": (in_dim, HIDDEN), "gate": (2 * HIDDEN, HIDDEN),
              "recur": (HIDDEN, HIDDEN), "out": (HIDDEN, action_dim)}
    keys = jax.random.split(key, len(shapes))
    return {name: jax.random.normal(k, shape) / np.sqrt(shape[0])
            for (name, shape), k in zip(shapes.items(), keys, strict=True)}


def interleaved_times(fns: dict, repeats: int) -> dict[str, np.ndarray]:
    """Per name, an array [repeats, 2] of (wall, CPU) seconds; the fns run in turn, so that
    load from other processes hits them alike. CPU time counts this process's threads only."""
    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            wall, cpu = time.perf_counter(), time.process_time()
            fn()
            times[name].append((time.perf_counter() - wall, time.process_time() - cpu))
    return {name: np.array(values) for name, values in times.items()}


def policy_scan(policy, chunk: int):
    """The policy alone, scanned over a chunk of given observations (no env, no callback).

    Each step gets its own image, so XLA cannot hoist the image encoder out of the loop."""

    @jax.jit
    def scan(params, carry, obs, images, key):
        def body(carry, inputs):
            image, step_key = inputs
            carry, action = policy(params, carry, {**obs, "image": image}, step_key)
            return carry, action
        return jax.lax.scan(body, carry, (images, jax.random.split(key, chunk)))

    return scan


def chunk_fns(envs: EnvBatch, policy, params, carry, chunk: int) -> tuple[dict, dict]:
    """One-chunk closures for: policy alone, env alone, scan driver, loop driver; and the
    seconds of each driver's first call (compilation included)."""
    obs = {k: jnp.asarray(v) for k, v in envs.reset().items()}
    scan = policy_scan(policy, chunk)
    rng = np.random.default_rng(0)
    images = jnp.asarray(rng.integers(0, 256, (chunk, *obs["image"].shape), np.uint8))
    actions = rng.uniform(-1, 1, (chunk, envs.num_envs, envs.spec.action_dim)).astype(np.float32)

    def env_steps():
        for action in actions:
            envs.step(action)

    fns = {"policy": lambda: jax.block_until_ready(scan(params, carry, obs, images, KEY)),
           "env": env_steps}
    first = {}
    for mode in ("loop",):
        collector = Collector(envs, policy, chunk=chunk)
        start = time.perf_counter()
        collector.run(params, carry, KEY)
        first[mode] = time.perf_counter() - start
        fns[mode] = functools.partial(collector.run, params, carry, KEY)
    fns["policy"]()
    return fns, first


def boundary_rows(name: str, make_batch, chunk: int, policy_name: str = "stand-in",
                  num_envs_list=(1, 2)) -> list[str]:
    """Rows: per driver, median wall, min wall and median CPU microseconds per agent step of
    collect, env, policy and the boundary (collect - env - policy)."""
    rows = []
    for num_envs in num_envs_list:
        envs = make_batch(num_envs)
        policy, params, carry = make_policy(policy_name, envs)
        fns, first = chunk_fns(envs, policy, params, carry, chunk)
        times = {k: v / chunk * 1e6 for k, v in interleaved_times(fns, REPEATS).items()}
        stats = {k: (np.median(v[:, 0]), v[:, 0].min(), np.median(v[:, 1]))
                 for k, v in times.items()}
        for mode in ("loop",):
            boundary = np.subtract(np.subtract(stats[mode], stats["env"]), stats["policy"])
            cells = [stats[mode], stats["env"], stats["policy"]]
            rows.append(f"| {name} | {policy_name} | {num_envs} | {chunk} | {mode} | "
                        + " | ".join("{:.0f} / {:.0f} / {:.0f}".format(*c) for c in cells)
                        + " | **{:.0f} / {:.0f} / {:.0f}** | ".format(*boundary)
                        + f"{first[mode]:.2f} |")
            print(rows[-1], flush=True)
        envs.close()
    return rows


def make_policy(name: str, envs: EnvBatch):
    """(policy, params, initial carry): the stand-in, or the real agent's acting step."""
    spec = envs.spec
    if name == "stand-in":
        params = standin_params(spec.obs_shape, spec.action_dim, jax.random.PRNGKey(0))
        return standin_policy, params, jnp.zeros((envs.num_envs, HIDDEN))
    from vsgjax.agents import make_agent

    agent = make_agent(make_config("bbs_basic", "vsg", name.removeprefix("vsg-")), spec)

    def policy(params, carry, obs, key):
        return agent.policy_step(params, carry, obs, key, mode="train")

    params = agent.init(jax.random.PRNGKey(0)).params
    return policy, params, agent.initial_carry(envs.num_envs)


def bare_env_rate(task: str, steps: int) -> tuple[float, float]:
    """Agent steps per second (and env steps per second) of one env with random actions."""
    env_cfg = make_config(task, size="debug").env
    env = make_env(env_cfg, seed=0)
    env.reset()

    def run():
        for _ in range(steps):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                env.reset()

    run()
    seconds = median_times(run, 3)[0]
    env.close()
    return steps / seconds, steps * env_cfg.action_repeat / seconds


def load_average() -> str:
    return " ".join(f"{x:.1f}" for x in os.getloadavg()) + f" ({os.cpu_count()} cores)"


def main() -> None:
    chunk = DEFAULT_CHUNK
    lines = ["## Collection (`vsgjax/data/collect.py`, `vsgjax/envs/`)", "",
             "Bare env step rates, one env in one process, random actions:", "",
             "| task | agent steps/s | env steps/s (x action repeat) |", "|---|---|---|"]
    for task, steps in (("bbs_basic", 300), ("dmc_walker_walk", 30), ("atari_pong", 300)):
        agent_rate, env_rate = bare_env_rate(task, steps)
        lines.append(f"| {task} | {agent_rate:.0f} | {env_rate:.0f} |")
        print(lines[-1], flush=True)
    lines += ["", f"Per agent step, microseconds: **median wall / min wall / median CPU** over "
              f"{REPEATS} chunks, the four measurements interleaved (CPU: this process's "
              "threads, not env worker processes). Compilation excluded (`first call` includes "
              "it). `boundary = collect - env - policy` is the cost of crossing between JAX and "
              "Python; `policy` is the policy scanned alone over a chunk of stored observations. "
              f"N = 2 runs the envs in worker processes. Load average before: {load_average()}.",
              "",
              "| env | policy | N | chunk | driver | collect | env | policy | boundary "
              "| first call (s) |", "|---|---|---|---|---|---|---|---|---|---|"]
    lines += boundary_rows("fake", fake_batch, chunk)
    lines += boundary_rows("fake", fake_batch, TRAIN_CHUNK, "vsg-small", (1,))
    lines += boundary_rows("fake", fake_batch, chunk, "vsg-small", (1,))
    bbs_cfg = make_config("bbs_basic", size="debug").env
    lines += boundary_rows("bbs_basic", lambda n: make_env_batch(bbs_cfg, 0, n), chunk)
    lines += ["", f"Load average after: {load_average()}."]
    text = "\n".join(lines) + "\n"
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text)


if __name__ == "__main__":
    main()
