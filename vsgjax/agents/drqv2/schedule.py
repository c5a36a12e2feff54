"""DrQ-v2's exploration-std schedule (facebookresearch/drqv2 ``utils.py``: ``schedule``, its
``'linear(init,final,duration)'`` form, the one every ``cfgs/task`` file uses)."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def linear(step: jax.Array | int, init: float, final: float, duration: float) -> jax.Array:
    """``mix = clip(step / duration, 0, 1); (1 - mix) * init + mix * final`` (float32).

    ``step`` counts agent steps (the authors' ``global_step``)."""
    mix = jnp.clip(jnp.asarray(step, jnp.float32) / float(duration), 0.0, 1.0)
    return (1.0 - mix) * init + mix * final
