"""SVSG: the purely stochastic, sparse-gated model (no deterministic state).

The sparse cell's recurrent state is the Gaussian latent ``z`` itself; the gate decides which
latent units are resampled and which are copied::

    x = ELU(Dense([z_prev, a_prev]));  (ĉ, g, p) = sparse cell(x, z_prev)
    prior ẑ ~ stats(ELU(Dense(ĉ)));          z_prior = g ⊙ ẑ_prior + (1 - g) ⊙ z_prev
    post  ẑ ~ stats(ELU(Dense([ĉ, e])));     z_post  = g ⊙ ẑ_post  + (1 - g) ⊙ z_prev  (same g)
    feat = z

(with GateL0RD's ReTanh gate the continuous ``Λ`` takes the place of ``g`` in both updates)

A state's ``dist`` is the distribution of the candidate ``ẑ``; the world model's masked KL
multiplies its per-dimension KL by ``g``.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from vsgjax.agents.dreamer.cells import apply_gate, cell_init, dense, dense_init, sparse_gru_cell
from vsgjax.agents.dreamer.dynamics.base import Dynamics, SVSGState


@dataclass(frozen=True)
class SVSG(Dynamics):
    def __post_init__(self):
        super().__post_init__()
        if self.cfg.classes != 0:
            raise ValueError(
                f"SVSG gates its latent per unit and needs Gaussian latents (model.classes=0), "
                f"got model.classes={self.cfg.classes}"
            )

    @property
    def gated(self) -> bool:
        return True

    @property
    def feat_dim(self) -> int:
        return self.cfg.stoch

    def init(self, key: jax.Array, embed_dim: int, action_dim: int) -> dict:
        cfg = self.cfg
        keys = jax.random.split(key, 7)
        return {
            "img_in": dense_init(keys[0], cfg.stoch + action_dim, cfg.hidden),
            "cell": cell_init(keys[1], cfg.hidden, cfg.stoch, cfg.cell_norm),
            **self._stats_init(keys[2:], cfg.stoch, "cand", cfg.stoch, embed_dim),
        }

    def initial(self) -> SVSGState:
        stoch, dist = self.latent.zeros()
        return SVSGState(stoch, dist, jnp.zeros_like(stoch), jnp.zeros_like(stoch))

    def _prior(self, params, prev, action, key) -> tuple[SVSGState, jax.Array, jax.Array]:
        """Prior state, the cell's candidate ``ĉ`` (which the posterior also reads) and the
        weight its update used (which the posterior's update uses too)."""
        cell_key, stoch_key = jax.random.split(key)
        inputs = jnp.concatenate([prev.stoch, action], -1)
        x = jax.nn.elu(dense(params["img_in"], inputs, self.dtype))
        cfg = self.cfg
        out = sparse_gru_cell(params["cell"], prev.stoch, x, cell_key, cfg.gate_bias,
                              cfg.gate_mode, self.dtype, self.gate)
        dist = self._prior_dist(params, out.candidate)
        stoch = apply_gate(self.gate.kind, out.weight, dist.sample(stoch_key), prev.stoch)
        return SVSGState(stoch, dist, out.gate, out.gate_logit), out.candidate, out.weight

    def img_step(self, params, prev, action, key):
        return self._prior(params, prev, action, key)[0]

    def _obs_step_projected(self, params, prev, action, embed_proj, key):
        prior_key, post_key = jax.random.split(key)
        prior, candidate, weight = self._prior(params, prev, action, prior_key)
        dist = self._posterior_dist(params, "cand", candidate, embed_proj)
        stoch = apply_gate(self.gate.kind, weight, dist.sample(post_key), prev.stoch)
        return prior._replace(stoch=stoch, dist=dist), prior

    def feat(self, state):
        return state.stoch
