"""Finger (``finger.xml``, elliptic cones, hinge friction loss, 2 substeps of 10 ms): spin.

Every observation is a sensor, as in dm_control: ``position`` (proximal and distal angles, tip
(x, z) relative to the spinner: 4), ``velocity`` (3 joint velocities), ``touch`` (log1p of the
two fingertip touch sensors: 2). Reward 1 while the spinner turns faster than 15 rad/s
clockwise. The task's model edits (every episode in dm_control, once here): hinge damping .03,
target and tip sites transparent."""

from __future__ import annotations

import jax
import jax.numpy as jnp
from dm_control.suite import finger
from mujoco import mjx

from vsgjax.envs.mjx import named, randomizers
from vsgjax.envs.mjx.core import TaskSpec

CONTROL_TIMESTEP = 0.02
SPIN_VELOCITY = 15.0
MAX_ATTEMPTS = 1000


def edit_spin(model):
    model.site("target").rgba[3] = 0
    model.site("tip").rgba[3] = 0
    model.dof_damping[model.joint("hinge").dofadr[0]] = 0.03


def in_contact(phys, data) -> jax.Array:
    """Whether any contact is active (MuJoCo's ``ncon > 0``) after ``fwd_position``."""
    contact = mjx.fwd_position(phys.mx, data)._impl.contact
    return jnp.any(contact.dist < contact.includemargin)


def init(key, phys, data):
    """dm_control's joint randomizer, redrawn until no geoms touch (at most 1000 draws)."""

    def draw(carry):
        key, _, attempts = carry
        key, sub = jax.random.split(key)
        qpos = randomizers.limited_and_rotational_joints(sub, phys.mj, data.qpos)
        return key, qpos, attempts + 1

    def touching(carry):
        _, qpos, attempts = carry
        return in_contact(phys, data.replace(qpos=qpos)) & (attempts < MAX_ATTEMPTS)

    _, qpos, _ = jax.lax.while_loop(touching, draw, draw((key, data.qpos, 0)))
    return data.replace(qpos=qpos), {}


def observe(phys, data, info):
    def xz(name):
        return named.sensor(phys, data, name)[jnp.array([0, 2])]

    tip = xz("tip") - xz("spinner")
    sensors = [named.sensor(phys, data, n) for n in ("proximal", "distal", "proximal_velocity",
                                                     "distal_velocity", "hinge_velocity")]
    touch = jnp.concatenate([named.sensor(phys, data, "touchtop"),
                             named.sensor(phys, data, "touchbottom")])
    return {"position": jnp.concatenate([*sensors[:2], tip]),
            "velocity": jnp.concatenate(sensors[2:]), "touch": jnp.log1p(touch)}


def reward(phys, data, info):
    hinge_velocity = named.sensor(phys, data, "hinge_velocity")[0]
    return (hinge_velocity <= -SPIN_VELOCITY).astype(jnp.float32)


TASKS = {"spin": TaskSpec("finger", "spin", finger.get_model_and_assets, init, observe,
                          reward, ("position", "velocity", "touch"), CONTROL_TIMESTEP,
                          edit_spin)}
