"""dm_control's ``randomize_limited_and_rotational_joints`` in JAX (``suite/utils``).

Limited hinges and slides are drawn uniformly in their range, unlimited hinges uniformly in
``[-pi, pi]``; unlimited slides keep their value. (Ball and free joints, which dm_control
also randomises, do not occur in the domains ported here and raise.)
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
import numpy as np


def limited_and_rotational_joints(key: jax.Array, model: mujoco.MjModel,
                                  qpos: jax.Array) -> jax.Array:
    """``qpos`` with every limited joint and unlimited hinge redrawn (one draw per joint)."""
    hinge, slide = mujoco.mjtJoint.mjJNT_HINGE, mujoco.mjtJoint.mjJNT_SLIDE
    if np.any((model.jnt_type != hinge) & (model.jnt_type != slide)):
        raise NotImplementedError("only hinge and slide joints are randomised")
    limited = model.jnt_limited.astype(bool)
    drawn = limited | (model.jnt_type == hinge)
    low = np.where(limited, model.jnt_range[:, 0], -np.pi)
    high = np.where(limited, model.jnt_range[:, 1], np.pi)
    values = jax.random.uniform(key, (model.njnt,), minval=low, maxval=high)
    adr = model.jnt_qposadr
    return qpos.at[adr[drawn]].set(values[drawn].astype(qpos.dtype))


def uniform(key: jax.Array, low: float, high: float, shape=()) -> jax.Array:
    """``numpy.random.uniform(low, high, shape)`` as float32."""
    return jax.random.uniform(key, shape, jnp.float32, low, high)
