"""dm_control's ``rewards.tolerance`` in JAX (``dm_control/utils/rewards.py``).

``tolerance(x, bounds, margin, sigmoid, value_at_margin)`` is 1 inside ``[lower, upper]`` and
decays with the distance ``d`` to the nearest bound, measured in units of ``margin``, so that
the value at ``d = 1`` is ``value_at_margin``. Bounds, margin and sigmoid are Python constants
(checked when traced); ``x`` is an array.
"""

from __future__ import annotations

import math

import jax.numpy as jnp

DEFAULT_VALUE_AT_MARGIN = 0.1
_ZERO_ALLOWED = ("cosine", "linear", "quadratic")  # sigmoids that accept value_at_margin == 0


def sigmoid(x, value_at_1: float, kind: str):
    """1 at ``x == 0``, ``value_at_1`` at ``|x| == 1``, in [0, 1] elsewhere."""
    low_ok = value_at_1 >= 0 if kind in _ZERO_ALLOWED else value_at_1 > 0
    if not (low_ok and value_at_1 < 1):
        raise ValueError(f"value_at_margin={value_at_1} is out of range for sigmoid {kind!r}")
    if kind == "gaussian":
        scale = math.sqrt(-2 * math.log(value_at_1))
        return jnp.exp(-0.5 * (x * scale) ** 2)
    if kind == "hyperbolic":
        return 1 / jnp.cosh(x * math.acosh(1 / value_at_1))
    if kind == "long_tail":
        return 1 / ((x * math.sqrt(1 / value_at_1 - 1)) ** 2 + 1)
    if kind == "reciprocal":
        return 1 / (jnp.abs(x) * (1 / value_at_1 - 1) + 1)
    if kind == "cosine":
        scaled = x * math.acos(2 * value_at_1 - 1) / math.pi
        return jnp.where(jnp.abs(scaled) < 1, (1 + jnp.cos(math.pi * scaled)) / 2, 0.0)
    if kind == "linear":
        scaled = x * (1 - value_at_1)
        return jnp.where(jnp.abs(scaled) < 1, 1 - scaled, 0.0)
    if kind == "quadratic":
        scaled = x * math.sqrt(1 - value_at_1)
        return jnp.where(jnp.abs(scaled) < 1, 1 - scaled ** 2, 0.0)
    if kind == "tanh_squared":
        return 1 - jnp.tanh(x * math.atanh(math.sqrt(1 - value_at_1))) ** 2
    raise ValueError(f"unknown sigmoid {kind!r}")


def tolerance(x, bounds=(0.0, 0.0), margin: float = 0.0, sigmoid_kind: str = "gaussian",
              value_at_margin: float = DEFAULT_VALUE_AT_MARGIN):
    """1 where ``lower <= x <= upper``, else ``sigmoid(distance / margin)`` (0 if margin 0)."""
    lower, upper = bounds
    if lower > upper:
        raise ValueError("lower bound must be <= upper bound")
    if margin < 0:
        raise ValueError("margin must be non-negative")
    x = jnp.asarray(x, jnp.float32)
    in_bounds = (lower <= x) & (x <= upper)
    if margin == 0:
        return jnp.where(in_bounds, 1.0, 0.0)
    distance = jnp.where(x < lower, lower - x, x - upper) / margin
    return jnp.where(in_bounds, 1.0, sigmoid(distance, value_at_margin, sigmoid_kind))
