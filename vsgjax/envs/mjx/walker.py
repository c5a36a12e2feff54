"""Planar walker (``walker.xml``, plane-capsule contacts, 10 substeps of 2.5 ms): stand, walk.

Observation: ``orientations`` (xx, xz of the 7 bodies: 14), ``height`` (torso z: 1; a scalar in
dm_control), ``velocity`` (9)."""

from __future__ import annotations

import functools

import numpy as np
from dm_control.suite import walker

from vsgjax.envs.mjx import named, randomizers
from vsgjax.envs.mjx.core import TaskSpec
from vsgjax.envs.mjx.rewards import tolerance

CONTROL_TIMESTEP = 0.025
STAND_HEIGHT = 1.2
WALK_SPEED = 1.0


def init(key, phys, data):
    """dm_control's joint randomizer: the torso pitch ~ U(-pi, pi), limbs ~ U(range)."""
    return data.replace(qpos=randomizers.limited_and_rotational_joints(key, phys.mj,
                                                                      data.qpos)), {}


def observe(phys, data, info):
    bodies = np.arange(1, phys.mj.nbody)
    torso = named.body(phys, "torso")
    return {"orientations": named.xmat(data, bodies, ("xx", "xz")).ravel(),
            "height": data.xpos[torso, 2:3], "velocity": data.qvel}


def reward(phys, data, info, *, move_speed: float):
    """stand = (3 standing + upright) / 4; walking multiplies by (5 move + 1) / 6."""
    torso = named.body(phys, "torso")
    standing = tolerance(data.xpos[torso, 2], (STAND_HEIGHT, float("inf")),
                         margin=STAND_HEIGHT / 2)
    upright = (1 + data.xmat[torso, 2, 2]) / 2
    stand = (3 * standing + upright) / 4
    if move_speed == 0:
        return stand
    speed = named.sensor(phys, data, "torso_subtreelinvel")[0]
    move = tolerance(speed, (move_speed, float("inf")), margin=move_speed / 2,
                     value_at_margin=0.5, sigmoid_kind="linear")
    return stand * (5 * move + 1) / 6


def _spec(task: str, speed: float) -> TaskSpec:
    return TaskSpec("walker", task, walker.get_model_and_assets, init, observe,
                    functools.partial(reward, move_speed=speed),
                    ("orientations", "height", "velocity"), CONTROL_TIMESTEP)


TASKS = {"stand": _spec("stand", 0.0), "walk": _spec("walk", WALK_SPEED)}

