"""Cartpole (``cartpole.xml``, RK4, no contacts): balance and swingup with dm_control's smooth
reward. Observation: ``position`` (cart x, pole cos, pole sin: 3), ``velocity`` (2)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from dm_control.suite import cartpole

from vsgjax.envs.mjx import named
from vsgjax.envs.mjx.core import TaskSpec
from vsgjax.envs.mjx.rewards import tolerance

POLE = 2  # body id of pole_1 (world 0, cart 1)


def init(key, phys, data, *, swing_up: bool):
    """Swingup: cart ~ N(0, .01), pole ~ pi + N(0, .01); balance: cart ~ U(-.1, .1), pole ~
    U(-.034, .034). Both: qvel ~ N(0, .01)."""
    k_cart, k_pole, k_vel = jax.random.split(key, 3)
    if swing_up:
        cart = 0.01 * jax.random.normal(k_cart)
        pole = np.pi + 0.01 * jax.random.normal(k_pole)
    else:
        cart = jax.random.uniform(k_cart, (), minval=-0.1, maxval=0.1)
        pole = jax.random.uniform(k_pole, (), minval=-0.034, maxval=0.034)
    qpos = jnp.stack([cart, pole]).astype(data.qpos.dtype)
    qvel = 0.01 * jax.random.normal(k_vel, (phys.mj.nv,), data.qvel.dtype)
    return data.replace(qpos=qpos, qvel=qvel), {}


def observe(phys, data, info):
    pole = named.xmat(data, np.array([POLE]), ("zz", "xz")).ravel()
    return {"position": jnp.concatenate([data.qpos[:1], pole]), "velocity": data.qvel}


def reward(phys, data, info):
    """upright * small_control * small_velocity * centered (each mapped into [0.5 or .8, 1])."""
    upright = (data.xmat[POLE:, 2, 2] + 1) / 2
    centered = (1 + tolerance(data.qpos[0], margin=2)) / 2
    small_control = tolerance(data.ctrl, margin=1, value_at_margin=0,
                              sigmoid_kind="quadratic")[0]
    small_control = (4 + small_control) / 5
    small_velocity = (1 + tolerance(data.qvel[1:], margin=5).min()) / 2
    return upright.mean() * small_control * small_velocity * centered


def _spec(task: str, swing_up: bool) -> TaskSpec:
    return TaskSpec("cartpole", task, cartpole.get_model_and_assets,
                    functools.partial(init, swing_up=swing_up), observe, reward,
                    ("position", "velocity"))


TASKS = {"balance": _spec("balance", False), "swingup": _spec("swingup", True)}
