"""SSM: PlaNet's purely stochastic baseline (no deterministic path, no gates)::

    x = ELU(Dense([flat(z_prev), a_prev]))
    prior = stats(ELU(Dense(x)));  posterior = stats(ELU(Dense([x, e])));  feat = flat(z)
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from vsgjax.cells import dense, dense_init
from vsgjax.dynamics.base import Dynamics, SSMState


@dataclass(frozen=True)
class SSM(Dynamics):
    @property
    def gated(self) -> bool:
        return False

    @property
    def feat_dim(self) -> int:
        return self.latent.flat_dim

    def init(self, key: jax.Array, embed_dim: int, action_dim: int) -> dict:
        cfg, latent = self.cfg, self.latent
        keys = jax.random.split(key, 6)
        return {
            "img_in": dense_init(keys[0], latent.flat_dim + action_dim, cfg.hidden),
            "img_out": dense_init(keys[1], cfg.hidden, cfg.hidden),
            "img_stats": dense_init(keys[2], cfg.hidden, latent.stats_dim),
            "obs_hidden": dense_init(keys[3], cfg.hidden, cfg.hidden),
            "obs_embed": dense_init(keys[4], embed_dim, cfg.hidden, bias=False),
            "obs_stats": dense_init(keys[5], cfg.hidden, latent.stats_dim),
        }

    def initial(self) -> SSMState:
        return SSMState(*self.latent.zeros())

    def _prior(self, params, prev, action, key) -> tuple[SSMState, jax.Array]:
        """Prior state and the transition's hidden ``x`` (which the posterior also reads)."""
        inputs = jnp.concatenate([self.latent.flatten(prev.stoch), action], -1)
        x = jax.nn.elu(dense(params["img_in"], inputs))
        hidden = jax.nn.elu(dense(params["img_out"], x))
        dist = self.latent.from_raw(dense(params["img_stats"], hidden))
        return SSMState(dist.sample(key), dist), x

    def img_step(self, params, prev, action, key):
        return self._prior(params, prev, action, key)[0]

    def project_embed(self, params, embed):
        return dense(params["obs_embed"], embed)

    def _obs_step_projected(self, params, prev, action, embed_proj, key):
        prior_key, post_key = jax.random.split(key)
        prior, x = self._prior(params, prev, action, prior_key)
        hidden = jax.nn.elu(dense(params["obs_hidden"], x) + embed_proj)
        dist = self.latent.from_raw(dense(params["obs_stats"], hidden))
        return SSMState(dist.sample(post_key), dist), prior

    def feat(self, state):
        return self.latent.flatten(state.stoch)
