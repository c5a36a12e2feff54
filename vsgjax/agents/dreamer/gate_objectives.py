"""The gated models' gate objectives (``wm.gate_objective``), for VSG, SVSG and VSGPro alike.

Over the posterior gates of a ``[B, T]`` batch, ``D`` units, ``p = σ(logit)`` the Bernoulli
gate's probability, ``p̄_i = mean_{B,T} p_i`` unit ``i``'s open rate::

    release   α · max(mean_{B,T} Σ_i KL(Bern(p) ‖ Bern(κ)), free)       (the VSG release)
    rate      λ · mean_{B,T,i} p                                        (closing is free)
    rate_kl   α · max(Σ_i KL(Bern(p̄_i) ‖ Bern(κ)), free)                (the rate, not p, to κ)
    gatel0rd  λ · mean_{B,T,i} Θ(Λ)                                      (GateL0RD's L0)

``release``, ``rate`` and ``rate_kl`` keep the release's Bernoulli gate with its straight-through
gradient; ``gatel0rd`` swaps it for GateL0RD's ReTanh gate (:mod:`vsgjax.agents.dreamer.cells`):
``Λ = max(0, tanh(u + ε))`` updates the state continuously and ``Θ(Λ) = [Λ > 0]`` passes the
identity gradient to ``Λ``, so only an opening costs: at ``Λ = 0`` the penalty and its gradient
are 0. ``rate``'s gradient ``λ·p(1 − p)/N`` per logit only ever pushes toward closing (E[Θ] of
a Bernoulli gate is ``p``, so it is the same expected count of openings). ``rate_kl`` asks each
unit to open at the paper's rate κ on average and leaves ``p`` free to depend on the state (a
unit closed for a stretch and open at once costs nothing if its rate is κ).

Settings: ``α, κ, free`` are ``wm.gate_alpha``, ``wm.gate_kappa``, ``wm.gate_free`` (the
release's); ``λ`` is ``wm.gate_lambda`` (default 1: THICK's sparsity scale, a GateL0RD context in
a DreamerV2 world model whose loss is ours); the ReTanh gate's noise std is ``wm.gate_noise``
(default 0.1: GateL0RD's ``gate_noise_level`` and THICK's task configs). docs/models.md has the
sources.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from vsgjax.agents.dreamer import gates
from vsgjax.agents.dreamer.cells import BERNOULLI_GATE, RETANH, GateCell
from vsgjax.agents.dreamer.settings import GATE_OBJECTIVES, WorldModelConfig

RELEASE, RATE, RATE_KL, GATEL0RD = GATE_OBJECTIVES
# The loss term each objective adds to the world-model loss, and its unscaled value's metric.
LOSS_NAMES = {RELEASE: ("gate_loss", "gate_kl"), RATE: ("gate_rate_loss", "gate_rate"),
              RATE_KL: ("gate_rate_kl_loss", "gate_rate_kl"),
              GATEL0RD: ("gate_l0_loss", "gate_l0")}


def _check(objective: str) -> None:
    if objective not in GATE_OBJECTIVES:
        raise ValueError(f"unknown gate objective {objective!r}; valid: "
                         f"{', '.join(GATE_OBJECTIVES)}")


def gate_cell(wm: WorldModelConfig) -> GateCell:
    """The sparse cell's gate an objective trains: GateL0RD's ReTanh gate for ``gatel0rd``,
    the release's Bernoulli gate otherwise."""
    _check(wm.gate_objective)
    if wm.gate_objective == GATEL0RD:
        return GateCell(RETANH, wm.gate_noise)
    return BERNOULLI_GATE


RATE_CLIP = 1e-6  # p̄ is kept in [1e-6, 1 - 1e-6]: a finite gradient for every unit


def rate_kl(logit: jax.Array, kappa: float) -> jax.Array:
    """``Σ_i KL(Bern(p̄_i) ‖ Bern(κ))``: ``p̄_i`` the mean of ``σ(logit)`` over every axis but
    the last (units)."""
    rate = jax.nn.sigmoid(logit).reshape(-1, logit.shape[-1]).mean(0)
    return gates.probability_kl(jnp.clip(rate, RATE_CLIP, 1.0 - RATE_CLIP), kappa).sum()


def gate_loss(wm: WorldModelConfig, gate: jax.Array, logit: jax.Array
              ) -> tuple[dict[str, jax.Array], dict[str, jax.Array]]:
    """``(losses, metrics)`` of objective ``wm.gate_objective`` on posterior gates ``[..., D]``:
    ``gate`` the straight-through 0/1 gate (``Θ`` for gatel0rd), ``logit`` the Bernoulli logit.
    ``losses`` holds the one term the objective adds (:data:`LOSS_NAMES`), ``metrics`` its
    unscaled value, and for the Bernoulli objectives the release's ``gate_kl`` besides."""
    objective = wm.gate_objective
    _check(objective)
    loss_name, value_name = LOSS_NAMES[objective]
    if objective == RELEASE:
        value = gates.mean_gate_kl(logit, wm.gate_kappa)
        loss = gates.sparsity_loss(logit, wm.gate_kappa, wm.gate_alpha, wm.gate_free)
    elif objective == RATE:
        value = jax.nn.sigmoid(logit).mean()
        loss = wm.gate_lambda * value
    elif objective == RATE_KL:
        value = rate_kl(logit, wm.gate_kappa)
        loss = wm.gate_alpha * jnp.maximum(value, wm.gate_free)
    else:
        value = gate.mean()
        loss = wm.gate_lambda * value
    metrics = {value_name: value}
    if objective in (RATE, RATE_KL):
        metrics["gate_kl"] = gates.mean_gate_kl(logit, wm.gate_kappa)
    return {loss_name: loss}, metrics
