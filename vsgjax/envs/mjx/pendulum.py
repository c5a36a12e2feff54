"""Pendulum (``pendulum.xml``, no contacts): swingup. Observation: ``orientation`` (pole zz,
xz: 2), ``velocity`` (1). Reward 1 while the pole is within 8 degrees of upright."""

from __future__ import annotations

import jax
import numpy as np
from dm_control.suite import pendulum

from vsgjax.envs.mjx import named
from vsgjax.envs.mjx.core import TaskSpec
from vsgjax.envs.mjx.rewards import tolerance

POLE = 1
ANGLE_BOUND = 8  # degrees
COSINE_BOUND = float(np.cos(np.deg2rad(ANGLE_BOUND)))


def init(key, phys, data):
    """Hinge ~ U(-pi, pi), at rest."""
    angle = jax.random.uniform(key, (1,), data.qpos.dtype, -np.pi, np.pi)
    return data.replace(qpos=angle), {}


def observe(phys, data, info):
    return {"orientation": named.xmat(data, POLE, ("zz", "xz")), "velocity": data.qvel[:1]}


def reward(phys, data, info):
    return tolerance(data.xmat[POLE, 2, 2], (COSINE_BOUND, 1.0))


TASKS = {"swingup": TaskSpec("pendulum", "swingup", pendulum.get_model_and_assets, init,
                             observe, reward, ("orientation", "velocity"))}
