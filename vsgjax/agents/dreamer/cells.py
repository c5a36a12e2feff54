"""Recurrent cells: the DreamerV2 GRU and the sparse-gated GRU of VSG, as pure functions.

Both cells share one fused dense layer (with bias) over ``[x, h_prev]`` giving ``3·D``
pre-activations, optionally LayerNorm-ed together, split as reset ``r``, candidate ``c``,
update ``u``::

    ĉ = tanh(σ(r) ⊙ c)              candidate (the reset scales the candidate pre-activation)
    logit = u + gate_bias            p = σ(logit), gate_bias = -1 by default
    GRU:  h = p ⊙ ĉ + (1 - p) ⊙ h_prev
    VSG:  g ~ Bernoulli(p)  (straight-through: forward hard 0/1, dg/dp = 1)
          h = g ⊙ ĉ + (1 - g) ⊙ h_prev  (a closed gate copies h_prev bit for bit)

Parameters are plain dicts built by the ``*_init`` functions; the small dense / LayerNorm
helpers here are also the building blocks of :mod:`vsgjax.agents.dreamer.dynamics`. ``dtype``
arguments are
the compute dtype of the dense layer's matmul (:mod:`vsgjax.agents.precision`); everything else, the
gate sample included, is float32.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from vsgjax.agents.precision import matmul

GATE_MODES = ("sample", "threshold")
LAYER_NORM_EPS = 1e-3  # tf.keras LayerNormalization default, as in the released code

_GLOROT = jax.nn.initializers.glorot_uniform()


def dense_init(key: jax.Array, in_dim: int, out_dim: int, bias: bool = True) -> dict:
    """Glorot-uniform kernel ``[in, out]`` and (optionally) zero bias."""
    params = {"kernel": _GLOROT(key, (in_dim, out_dim), jnp.float32)}
    if bias:
        params["bias"] = jnp.zeros(out_dim, jnp.float32)
    return params


def dense(params: dict, x: jax.Array, dtype=jnp.float32) -> jax.Array:
    """``x @ kernel (+ bias)`` on the last axis (matmul in ``dtype``, float32 out); any leading
    axes."""
    y = matmul(x, params["kernel"], dtype)
    return y + params["bias"] if "bias" in params else y


def layer_norm_init(dim: int) -> dict:
    return {"scale": jnp.ones(dim, jnp.float32), "bias": jnp.zeros(dim, jnp.float32)}


def layer_norm(params: dict, x: jax.Array) -> jax.Array:
    """LayerNorm over the last axis with learned scale and bias."""
    mean = x.mean(-1, keepdims=True)
    var = jnp.square(x - mean).mean(-1, keepdims=True)
    return (x - mean) * jax.lax.rsqrt(var + LAYER_NORM_EPS) * params["scale"] + params["bias"]


def cell_init(key: jax.Array, input_dim: int, state_dim: int, norm: bool) -> dict:
    """Params of either cell: fused dense ``[input + state] -> 3·state`` (+ LayerNorm)."""
    params = {"dense": dense_init(key, input_dim + state_dim, 3 * state_dim)}
    if norm:
        params["norm"] = layer_norm_init(3 * state_dim)
    return params


def _candidate_and_logit(
    params: dict, h_prev: jax.Array, x: jax.Array, gate_bias: float, dtype
) -> tuple[jax.Array, jax.Array]:
    """Candidate ``ĉ`` and update-gate logit ``u + gate_bias``."""
    pre = dense(params["dense"], jnp.concatenate([x, h_prev], -1), dtype)
    if "norm" in params:
        pre = layer_norm(params["norm"], pre)
    reset, cand, update = jnp.split(pre, 3, axis=-1)
    return jnp.tanh(jax.nn.sigmoid(reset) * cand), update + gate_bias


def gru_cell(params: dict, h_prev: jax.Array, x: jax.Array, gate_bias: float = -1.0,
             dtype=jnp.float32) -> jax.Array:
    """DreamerV2 GRU step: ``h = p ⊙ ĉ + (1 - p) ⊙ h_prev`` with ``p = σ(u + gate_bias)``."""
    cand, logit = _candidate_and_logit(params, h_prev, x, gate_bias, dtype)
    p = jax.nn.sigmoid(logit)
    return p * cand + (1.0 - p) * h_prev


class SparseCellOutput(NamedTuple):
    """Result of :func:`sparse_gru_cell`; all fields ``[D]``.

    ``gate`` is the straight-through sample (exactly 0/1 forward, gradient 1 w.r.t. the
    probability ``σ(gate_logit)``); ``candidate`` is ``ĉ`` (SVSG gates its own latent with it).
    """

    state: jax.Array
    candidate: jax.Array
    gate: jax.Array
    gate_logit: jax.Array


def straight_through_gate(logit: jax.Array, key: jax.Array, mode: str = "sample") -> jax.Array:
    """Hard 0/1 gate with the straight-through gradient of ``p = σ(logit)``.

    ``mode="sample"``: ``g ~ Bernoulli(p)``; ``mode="threshold"``: ``g = [p > 0.5]``
    (deterministic; ``key`` unused).
    The forward value is ``hard + (p - sg(p))`` = ``hard + 0`` exactly, and ``dg/dp = 1``.
    """
    if mode not in GATE_MODES:
        raise ValueError(f"unknown gate mode {mode!r}; valid: {', '.join(GATE_MODES)}")
    p = jax.nn.sigmoid(logit)
    hard = jax.random.bernoulli(key, p) if mode == "sample" else logit > 0
    return hard.astype(logit.dtype) + (p - jax.lax.stop_gradient(p))


@jax.custom_jvp
def gated_update(gate: jax.Array, new: jax.Array, old: jax.Array) -> jax.Array:
    """``g ⊙ new + (1 - g) ⊙ old`` for a gate that is exactly 0/1 in the forward pass.

    The forward pass is a pure selection (``jnp.where``, no arithmetic), so a closed gate
    reproduces ``old`` bit for bit (even subnormals, which CPU arithmetic flushes to zero);
    the derivatives are those of the linear formula: ``d/dg = new - old``, ``d/dnew = g``,
    ``d/dold = 1 - g``.
    """
    return jnp.where(gate > 0.5, new, old)


@gated_update.defjvp
def _gated_update_jvp(primals, tangents):
    gate, new, old = primals
    d_gate, d_new, d_old = tangents
    out = gated_update(gate, new, old)
    return out, d_gate * (new - old) + gate * d_new + (1.0 - gate) * d_old


def sparse_gru_cell(
    params: dict,
    h_prev: jax.Array,
    x: jax.Array,
    key: jax.Array,
    gate_bias: float = -1.0,
    mode: str = "sample",
    dtype=jnp.float32,
) -> SparseCellOutput:
    """VSG step: per-unit hard gate ``g``; open units take ``ĉ``, closed units keep ``h_prev``."""
    cand, logit = _candidate_and_logit(params, h_prev, x, gate_bias, dtype)
    gate = straight_through_gate(logit, key, mode)
    return SparseCellOutput(gated_update(gate, cand, h_prev), cand, gate, logit)
