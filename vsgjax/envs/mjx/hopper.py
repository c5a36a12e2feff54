"""Planar hopper (``hopper.xml``, plane-capsule contacts, 4 substeps of 5 ms): stand.

Observation: ``position`` (qpos without the root x: 6), ``velocity`` (7), ``touch`` (log1p of
the toe and heel touch sensors: 2)."""

from __future__ import annotations

import jax.numpy as jnp
from dm_control.suite import hopper

from vsgjax.envs.mjx import named, randomizers
from vsgjax.envs.mjx.core import TaskSpec
from vsgjax.envs.mjx.rewards import tolerance

CONTROL_TIMESTEP = 0.02
STAND_HEIGHT = 0.6


def init(key, phys, data):
    """dm_control's joint randomizer: the torso pitch ~ U(-pi, pi), limbs ~ U(range)."""
    return data.replace(qpos=randomizers.limited_and_rotational_joints(key, phys.mj,
                                                                      data.qpos)), {}


def touch(phys, data):
    return jnp.log1p(jnp.concatenate([named.sensor(phys, data, "touch_toe"),
                                      named.sensor(phys, data, "touch_heel")]))


def observe(phys, data, info):
    return {"position": data.qpos[1:], "velocity": data.qvel, "touch": touch(phys, data)}


def reward(phys, data, info):
    """standing (torso above foot in [0.6, 2]) * (4 + small control) / 5."""
    height = data.xipos[named.body(phys, "torso"), 2] - data.xipos[named.body(phys, "foot"), 2]
    standing = tolerance(height, (STAND_HEIGHT, 2.0))
    small_control = tolerance(data.ctrl, margin=1, value_at_margin=0,
                              sigmoid_kind="quadratic").mean()
    return standing * (small_control + 4) / 5


TASKS = {"stand": TaskSpec("hopper", "stand", hopper.get_model_and_assets, init, observe,
                           reward, ("position", "velocity", "touch"), CONTROL_TIMESTEP)}
