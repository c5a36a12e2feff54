"""Cheetah (``cheetah.xml``, plane-capsule contacts): run. Observation: ``position`` (qpos
without the root x: 8), ``velocity`` (9). Reward: torso subtree x-velocity / 10, capped at 1."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from dm_control.suite import cheetah
from mujoco import mjx

from vsgjax.envs.mjx import named
from vsgjax.envs.mjx.core import TaskSpec
from vsgjax.envs.mjx.rewards import tolerance

RUN_SPEED = 10
SETTLE_STEPS = 200  # physics steps with zero control before the episode starts


def init(key, phys, data):
    """Limited joints ~ U(range) (the root stays at qpos0), then 200 physics steps to settle.

    dm_control takes these steps with ``legacy_step``, whose first substep finishes a stale
    ``mj_step1``; here all 200 are plain ``mj_step`` from the drawn pose. ``time`` is reset."""
    m = phys.mj
    limited = m.jnt_limited.astype(bool)
    low, high = m.jnt_range[limited].T
    values = jax.random.uniform(key, low.shape, data.qpos.dtype, low, high)
    data = data.replace(qpos=data.qpos.at[m.jnt_qposadr[limited]].set(values))
    data = jax.lax.fori_loop(0, SETTLE_STEPS, lambda _, d: mjx.step(phys.mx, d), data)
    return data.replace(time=jnp.zeros_like(data.time)), {}


def observe(phys, data, info):
    return {"position": data.qpos[1:], "velocity": data.qvel}


def reward(phys, data, info):
    speed = named.sensor(phys, data, "torso_subtreelinvel")[0]
    return tolerance(speed, (RUN_SPEED, float("inf")), margin=RUN_SPEED, value_at_margin=0,
                     sigmoid_kind="linear")


TASKS = {"run": TaskSpec("cheetah", "run", cheetah.get_model_and_assets, init, observe,
                         reward, ("position", "velocity"))}
