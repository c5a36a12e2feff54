"""RSSM dynamics: DreamerV1 (Gaussian z), DreamerV2 (categorical z) and VSG (sparse-gated GRU).

::

    img_step:  x = ELU(Dense([flat(z_prev), a_prev]))
               h = GRU(x, h_prev)            (VSG: sparse-gated GRU, gate g ~ Bern(p))
               prior = stats(ELU(Dense(h)));  z ~ prior
    obs_step:  posterior = stats(ELU(Dense([h, e])));  z ~ posterior
               (same h as the prior, hence for VSG the same gate: gates never see e)
    feat:      [flat(z), h]
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from vsgjax.agents.dreamer.cells import cell_init, dense, dense_init, gru_cell, sparse_gru_cell
from vsgjax.agents.dreamer.dynamics.base import Dynamics, GatedRSSMState, RSSMState
from vsgjax.registry.agents import agent_entry


@dataclass(frozen=True)
class RSSM(Dynamics):
    """Recurrent state-space model; the sparse-gated cell when the model's registry entry is
    gated (VSG)."""

    def __post_init__(self):
        super().__post_init__()
        if self.cfg.deter <= 0:
            raise ValueError(
                f"model.deter must be positive for {self.name!r}, got {self.cfg.deter}"
            )

    @property
    def gated(self) -> bool:
        return agent_entry(self.name).gated

    @property
    def feat_dim(self) -> int:
        return self.latent.flat_dim + self.cfg.deter

    def init(self, key: jax.Array, embed_dim: int, action_dim: int) -> dict:
        cfg, latent = self.cfg, self.latent
        keys = jax.random.split(key, 7)
        return {
            "img_in": dense_init(keys[0], latent.flat_dim + action_dim, cfg.hidden),
            "cell": cell_init(keys[1], cfg.hidden, cfg.deter, cfg.cell_norm),
            **self._stats_init(keys[2:], cfg.deter, "deter", cfg.deter, embed_dim),
        }

    def initial(self) -> RSSMState | GatedRSSMState:
        stoch, dist = self.latent.zeros()
        deter = jnp.zeros(self.cfg.deter)
        if self.gated:
            return GatedRSSMState(deter, stoch, dist, jnp.zeros_like(deter), jnp.zeros_like(deter))
        return RSSMState(deter, stoch, dist)

    def img_step(self, params, prev, action, key):
        cell_key, stoch_key = jax.random.split(key)
        inputs = jnp.concatenate([self.latent.flatten(prev.stoch), action], -1)
        x = jax.nn.elu(dense(params["img_in"], inputs, self.dtype))
        if self.gated:
            cfg = self.cfg
            out = sparse_gru_cell(params["cell"], prev.deter, x, cell_key, cfg.gate_bias,
                                  cfg.gate_mode, self.dtype, self.gate)
            dist = self._prior_dist(params, out.state)
            return GatedRSSMState(
                out.state, dist.sample(stoch_key), dist, out.gate, out.gate_logit
            )
        deter = gru_cell(params["cell"], prev.deter, x, self.cfg.gate_bias, self.dtype)
        dist = self._prior_dist(params, deter)
        return RSSMState(deter, dist.sample(stoch_key), dist)

    def _obs_step_projected(self, params, prev, action, embed_proj, key):
        prior_key, post_key = jax.random.split(key)
        prior = self.img_step(params, prev, action, prior_key)
        dist = self._posterior_dist(params, "deter", prior.deter, embed_proj)
        return prior._replace(stoch=dist.sample(post_key), dist=dist), prior

    def feat(self, state):
        return jnp.concatenate([self.latent.flatten(state.stoch), state.deter], -1)
