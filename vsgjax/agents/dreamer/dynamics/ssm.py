"""SSM: PlaNet's purely stochastic baseline (no deterministic path, no gates)::

    x = ELU(Dense([flat(z_prev), a_prev]))
    prior = stats(ELU(Dense(x)));  posterior = stats(ELU(Dense([x, e])));  feat = flat(z)
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp

from vsgjax.agents.dreamer.cells import dense, dense_init
from vsgjax.agents.dreamer.dynamics.base import Dynamics, SSMState


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
            **self._stats_init(keys[1:], cfg.hidden, "hidden", cfg.hidden, embed_dim),
        }

    def initial(self) -> SSMState:
        return SSMState(*self.latent.zeros())

    def _prior(self, params, prev, action, key) -> tuple[SSMState, jax.Array]:
        """Prior state and the transition's hidden ``x`` (which the posterior also reads)."""
        inputs = jnp.concatenate([self.latent.flatten(prev.stoch), action], -1)
        x = jax.nn.elu(dense(params["img_in"], inputs, self.dtype))
        dist = self._prior_dist(params, x)
        return SSMState(dist.sample(key), dist), x

    def img_step(self, params, prev, action, key):
        return self._prior(params, prev, action, key)[0]

    def _obs_step_projected(self, params, prev, action, embed_proj, key):
        prior_key, post_key = jax.random.split(key)
        prior, x = self._prior(params, prev, action, prior_key)
        dist = self._posterior_dist(params, "hidden", x, embed_proj)
        return SSMState(dist.sample(post_key), dist), prior

    def feat(self, state):
        return self.latent.flatten(state.stoch)
