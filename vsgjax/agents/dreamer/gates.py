"""Gate sparsity loss (the release's; the other objectives: :mod:`.gate_objectives`) and gate
metrics.

``L_gate = α · max(mean_{B,T} Σ_units KL(Bern(p) ‖ Bern(κ)), free)`` with ``p = σ(logit)``,
computed from logits with ``log σ`` so saturated gates (``|logit|`` huge) stay finite.
Statistics take gate samples ``g`` shaped ``[B, T, D]`` or ``[T, D]`` (0/1 values).
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp


def _check_kappa(kappa: float) -> None:
    if isinstance(kappa, int | float) and not 0.0 < kappa < 1.0:
        raise ValueError(f"gate prior probability kappa must lie in (0, 1), got {kappa}")


def bernoulli_kl(logit: jax.Array, kappa: float) -> jax.Array:
    """Elementwise ``KL(Bern(σ(logit)) ‖ Bern(κ))``.

    ``= p·(log p - log κ) + (1 - p)·(log(1 - p) - log(1 - κ))`` with ``log p = log σ(logit)``
    and ``log(1 - p) = log σ(-logit)``: finite for any finite logit.
    """
    _check_kappa(kappa)
    p = jax.nn.sigmoid(logit)
    log_p = jax.nn.log_sigmoid(logit)
    log_not_p = jax.nn.log_sigmoid(-logit)
    return p * (log_p - math.log(kappa)) + (1.0 - p) * (log_not_p - math.log1p(-kappa))


def probability_kl(p: jax.Array, kappa: float) -> jax.Array:
    """Elementwise ``KL(Bern(p) ‖ Bern(κ))`` from probabilities ``p`` in ``[0, 1]`` (``0 log 0
    = 0``): for gates that have no logit (the ReTanh gate) and for open rates."""
    _check_kappa(kappa)
    return (jax.scipy.special.xlogy(p, p) - p * math.log(kappa)
            + jax.scipy.special.xlogy(1.0 - p, 1.0 - p) - (1.0 - p) * math.log1p(-kappa))


def mean_gate_kl(logit: jax.Array, kappa: float) -> jax.Array:
    """Gate KL summed over units (last axis) and averaged over all leading axes (scalar)."""
    return bernoulli_kl(logit, kappa).sum(-1).mean()


def sparsity_loss(logit: jax.Array, kappa: float, alpha: float, free: float) -> jax.Array:
    """``α · max(mean_gate_kl, free)``; no gradient while the mean KL is below ``free``."""
    return alpha * jnp.maximum(mean_gate_kl(logit, kappa), free)


def _as_batch(gate: jax.Array) -> jax.Array:
    if gate.ndim == 2:
        return gate[None]
    if gate.ndim != 3:
        raise ValueError(f"gate tensor must be [T, D] or [B, T, D], got shape {gate.shape}")
    return gate


def gate_metrics(gate: jax.Array, prob: jax.Array) -> dict[str, jax.Array]:
    """Gate metrics (all scalars, computed without gradient).

    * ``gate_units_per_step_{mean,std}``: open units per time step, over (B, T);
    * ``gate_updates_per_unit_{mean,std}``: times each unit opened over a sequence, over (B, D);
    * ``gate_open_fraction``: mean of ``g``; ``gate_prob_mean``: mean of ``p``.
    """
    gate = jax.lax.stop_gradient(_as_batch(gate))
    per_step = gate.sum(-1)  # [B, T]
    per_unit = gate.sum(1)  # [B, D]
    return {
        "gate_units_per_step_mean": per_step.mean(),
        "gate_units_per_step_std": per_step.std(),
        "gate_updates_per_unit_mean": per_unit.mean(),
        "gate_updates_per_unit_std": per_unit.std(),
        "gate_open_fraction": gate.mean(),
        "gate_prob_mean": jax.lax.stop_gradient(prob).mean(),
    }
