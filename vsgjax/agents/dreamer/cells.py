"""Recurrent cells: the DreamerV2 GRU and the sparse-gated GRU of VSG, as pure functions.

Both cells share one fused dense layer (with bias) over ``[x, h_prev]`` giving ``3·D``
pre-activations, optionally LayerNorm-ed together, split as reset ``r``, candidate ``c``,
update ``u``::

    ĉ = tanh(σ(r) ⊙ c)              candidate (the reset scales the candidate pre-activation)
    logit = u + gate_bias            p = σ(logit), gate_bias = -1 by default
    GRU:  h = p ⊙ ĉ + (1 - p) ⊙ h_prev
    VSG:  g ~ Bernoulli(p)  (straight-through: forward hard 0/1, dg/dp = 1)
          h = g ⊙ ĉ + (1 - g) ⊙ h_prev  (a closed gate copies h_prev bit for bit)

The sparse cell's gate is one of two kinds (:class:`GateCell`): the release's Bernoulli gate
above, or GateL0RD's ReTanh gate (``wm.gate_objective=gatel0rd``)::

    s = u + ε,  ε ~ N(0, noise²) (model.gate_mode=sample; none with threshold)
    Λ = max(0, tanh(s))            h = Λ ⊙ ĉ + (1 - Λ) ⊙ h_prev    (Λ = 0 copies h_prev)
    Θ = [Λ > 0]  (straight-through: forward hard 0/1, dΘ/dΛ = 1)

GateL0RD's gate network is a dense layer with a learned bias on ``[x, h_prev]``: here the
update slice ``u`` of the fused layer, without the fixed ``gate_bias``.

Parameters are plain dicts built by the ``*_init`` functions; the small dense / LayerNorm
helpers here are also the building blocks of :mod:`vsgjax.agents.dreamer.dynamics`. ``dtype``
arguments are
the compute dtype of the dense layer's matmul (:mod:`vsgjax.agents.precision`); everything else, the
gate sample included, is float32.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp

from vsgjax.agents.precision import matmul

GATE_MODES = ("sample", "threshold")
BERNOULLI, RETANH = "bernoulli", "retanh"  # the kinds of sparse gate (GateCell.kind)
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


def _candidate_and_update(
    params: dict, h_prev: jax.Array, x: jax.Array, dtype
) -> tuple[jax.Array, jax.Array]:
    """Candidate ``ĉ`` and the update gate's pre-activation ``u``."""
    pre = dense(params["dense"], jnp.concatenate([x, h_prev], -1), dtype)
    if "norm" in params:
        pre = layer_norm(params["norm"], pre)
    reset, cand, update = jnp.split(pre, 3, axis=-1)
    return jnp.tanh(jax.nn.sigmoid(reset) * cand), update


def _candidate_and_logit(
    params: dict, h_prev: jax.Array, x: jax.Array, gate_bias: float, dtype
) -> tuple[jax.Array, jax.Array]:
    """Candidate ``ĉ`` and update-gate logit ``u + gate_bias``."""
    cand, update = _candidate_and_update(params, h_prev, x, dtype)
    return cand, update + gate_bias


def gru_cell(params: dict, h_prev: jax.Array, x: jax.Array, gate_bias: float = -1.0,
             dtype=jnp.float32) -> jax.Array:
    """DreamerV2 GRU step: ``h = p ⊙ ĉ + (1 - p) ⊙ h_prev`` with ``p = σ(u + gate_bias)``."""
    cand, logit = _candidate_and_logit(params, h_prev, x, gate_bias, dtype)
    p = jax.nn.sigmoid(logit)
    return p * cand + (1.0 - p) * h_prev


class SparseCellOutput(NamedTuple):
    """Result of :func:`sparse_gru_cell`; all fields ``[D]``.

    ``gate`` is exactly 0/1 forward (1: open): the Bernoulli gate's straight-through sample
    (gradient 1 w.r.t. the probability ``σ(gate_logit)``) or the ReTanh gate's ``Θ(Λ)``
    (gradient 1 w.r.t. ``Λ``); ``gate_logit`` is the Bernoulli logit or the ReTanh gate's ``u``
    before the noise; ``weight`` is what the update used (``g``, or the continuous ``Λ``);
    ``candidate`` is ``ĉ`` (SVSG gates its own latent with it, :func:`apply_gate`).
    """

    state: jax.Array
    candidate: jax.Array
    gate: jax.Array
    gate_logit: jax.Array
    weight: jax.Array


@dataclass(frozen=True)
class GateCell:
    """The sparse cell's gate: ``kind`` (:data:`BERNOULLI` or :data:`RETANH`) and, for the
    ReTanh gate, the standard deviation ``noise`` of its pre-activation noise."""

    kind: str = BERNOULLI
    noise: float = 0.0

    def __post_init__(self):
        if self.kind not in (BERNOULLI, RETANH):
            raise ValueError(f"unknown gate kind {self.kind!r}; valid: {BERNOULLI}, {RETANH}")
        if not self.noise >= 0.0:
            raise ValueError(f"gate noise must be >= 0, got {self.noise}")


BERNOULLI_GATE = GateCell()  # the release's gate


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


def retanh_gate(update: jax.Array, key: jax.Array, noise: float, mode: str = "sample"
                ) -> tuple[jax.Array, jax.Array]:
    """GateL0RD's gate ``(Θ, Λ)``: ``Λ = max(0, tanh(u + ε))`` with ``ε ~ N(0, noise²)``
    (``mode="sample"``; no noise with ``"threshold"``) and ``Θ = [Λ > 0]`` with the
    straight-through (identity) gradient ``dΘ/dΛ = 1``."""
    if mode not in GATE_MODES:
        raise ValueError(f"unknown gate mode {mode!r}; valid: {', '.join(GATE_MODES)}")
    if mode == "sample":
        update = update + noise * jax.random.normal(key, update.shape, update.dtype)
    weight = jax.nn.relu(jnp.tanh(update))
    theta = (weight > 0).astype(weight.dtype) + (weight - jax.lax.stop_gradient(weight))
    return theta, weight


def open_probability(gate: GateCell, logit: jax.Array) -> jax.Array:
    """Probability that the gate opens at a sampled step: ``σ(logit)`` for the Bernoulli
    gate; ``P(u + ε > 0) = Φ(u / noise)`` for the ReTanh gate (``[u > 0]`` without noise)."""
    if gate.kind == BERNOULLI:
        return jax.nn.sigmoid(logit)
    if gate.noise == 0.0:
        return (logit > 0).astype(logit.dtype)
    return jax.scipy.stats.norm.cdf(logit / gate.noise)


def apply_gate(kind: str, weight: jax.Array, new: jax.Array, old: jax.Array) -> jax.Array:
    """The gated update ``w ⊙ new + (1 - w) ⊙ old``: :func:`gated_update` for the 0/1
    Bernoulli gate; for the ReTanh gate the continuous mix, ``old`` bit for bit where
    ``Λ = 0``."""
    if kind == BERNOULLI:
        return gated_update(weight, new, old)
    return jnp.where(weight > 0, weight * new + (1.0 - weight) * old, old)


def sparse_gru_cell(
    params: dict,
    h_prev: jax.Array,
    x: jax.Array,
    key: jax.Array,
    gate_bias: float = -1.0,
    mode: str = "sample",
    dtype=jnp.float32,
    gate: GateCell = BERNOULLI_GATE,
) -> SparseCellOutput:
    """VSG step: per-unit gate; open units take ``ĉ`` (the ReTanh gate: a fraction ``Λ`` of
    it), closed units keep ``h_prev``."""
    if gate.kind == RETANH:
        cand, update = _candidate_and_update(params, h_prev, x, dtype)
        theta, weight = retanh_gate(update, key, gate.noise, mode)
        return SparseCellOutput(apply_gate(RETANH, weight, cand, h_prev), cand, theta, update,
                                weight)
    cand, logit = _candidate_and_logit(params, h_prev, x, gate_bias, dtype)
    sample = straight_through_gate(logit, key, mode)
    return SparseCellOutput(gated_update(sample, cand, h_prev), cand, sample, logit, sample)
