"""DrQ-v2's truncated normal (facebookresearch/drqv2 ``utils.py``: ``TruncatedNormal``).

Not a truncated normal in the textbook sense: a ``torch.distributions.Normal(loc, scale)`` whose
``sample(clip)`` draws ``x = loc + clamp(eps * scale, -clip, clip)`` (no clip when ``clip`` is
None) and then clamps ``x`` to ``[low + eps, high - eps]`` = ``[-1 + 1e-6, 1 - 1e-6]`` with a
straight-through gradient (``x - x.detach() + clamped.detach()``: the value is clamped, the
gradient is that of the unclamped ``x``). ``log_prob`` and ``entropy`` are the Normal's (the
clamp and the clip are ignored), as the authors' metrics report them.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp

LOW, HIGH, EPS = -1.0, 1.0, 1e-6
_HALF_LOG_2PI = 0.5 * math.log(2.0 * math.pi)


def clamp_straight_through(x: jax.Array, low: float = LOW, high: float = HIGH,
                           eps: float = EPS) -> jax.Array:
    """``TruncatedNormal._clamp``: the value clamped to ``[low + eps, high - eps]``, the
    gradient of the identity."""
    clamped = jnp.clip(x, low + eps, high - eps)
    return x - jax.lax.stop_gradient(x) + jax.lax.stop_gradient(clamped)


def sample(key: jax.Array, mean: jax.Array, std: jax.Array | float,
           clip: float | None = None) -> jax.Array:
    """``TruncatedNormal(mean, std).sample(clip)`` (reparameterised: differentiable in ``mean``)."""
    noise = jax.random.normal(key, mean.shape, jnp.float32) * std
    if clip is not None:
        noise = jnp.clip(noise, -clip, clip)
    return clamp_straight_through(mean + noise)


def log_prob(x: jax.Array, mean: jax.Array, std: jax.Array | float) -> jax.Array:
    """``Normal(mean, std).log_prob(x)``, elementwise."""
    std = jnp.broadcast_to(jnp.asarray(std, jnp.float32), mean.shape)
    return -((x - mean) ** 2) / (2.0 * std**2) - jnp.log(std) - _HALF_LOG_2PI


def entropy(mean: jax.Array, std: jax.Array | float) -> jax.Array:
    """``Normal(mean, std).entropy()``, elementwise: ``0.5 + 0.5 log(2 pi) + log std``."""
    std = jnp.broadcast_to(jnp.asarray(std, jnp.float32), mean.shape)
    return 0.5 + _HALF_LOG_2PI + jnp.log(std)
