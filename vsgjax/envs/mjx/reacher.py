"""Reacher (``reacher.xml``, no contacts): easy (target radius .05) and hard (.015).

dm_control moves the target by editing ``model.geom_pos`` each episode; an MJX model is shared
by a batch, so the target's (x, y) lives in the state's ``info["target"]`` instead (the target
geom is not part of the dynamics: contacts are disabled). Observation: ``position`` (2 joint
angles), ``to_target`` (target - finger, x y), ``velocity`` (2)."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
from dm_control.suite import reacher

from vsgjax.envs.mjx import named, randomizers
from vsgjax.envs.mjx.core import TaskSpec
from vsgjax.envs.mjx.rewards import tolerance

BIG_TARGET, SMALL_TARGET = 0.05, 0.015


def init(key, phys, data):
    """Joints as dm_control's randomizer; target at angle ~ U(0, 2 pi), radius ~ U(.05, .2),
    placed at (r sin a, r cos a)."""
    k_joints, k_angle, k_radius = jax.random.split(key, 3)
    qpos = randomizers.limited_and_rotational_joints(k_joints, phys.mj, data.qpos)
    angle = randomizers.uniform(k_angle, 0.0, 2 * np.pi)
    radius = randomizers.uniform(k_radius, 0.05, 0.20)
    target = jnp.stack([radius * jnp.sin(angle), radius * jnp.cos(angle)])
    return data.replace(qpos=qpos), {"target": target}


def to_target(phys, data, info):
    return info["target"] - data.geom_xpos[named.geom(phys, "finger"), :2]


def observe(phys, data, info):
    return {"position": data.qpos, "to_target": to_target(phys, data, info),
            "velocity": data.qvel}


def reward(phys, data, info, *, target_size: float):
    radii = target_size + float(phys.mj.geom("finger").size[0])
    return tolerance(jnp.linalg.norm(to_target(phys, data, info)), (0.0, radii))


def set_target_size(model, size: float):
    model.geom("target").size[0] = size


def _spec(task: str, size: float) -> TaskSpec:
    return TaskSpec("reacher", task, reacher.get_model_and_assets, init, observe,
                    functools.partial(reward, target_size=size),
                    ("position", "to_target", "velocity"),
                    edit=functools.partial(set_target_size, size=size))


TASKS = {"easy": _spec("easy", BIG_TARGET), "hard": _spec("hard", SMALL_TARGET)}
