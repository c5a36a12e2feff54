"""Small gymnasium wrappers shared by every task family."""

from __future__ import annotations

import gymnasium


class DefaultSeed(gymnasium.Wrapper):
    """The first ``reset()`` without a seed uses ``seed``, so a made env is reproducible as is.

    Vector envs reset their members with ``seed=None`` when given no seed; with this wrapper each
    member still starts from the seed it was made with. The action space is seeded too.
    """

    def __init__(self, env: gymnasium.Env, seed: int):
        super().__init__(env)
        self._pending_seed = seed
        self.action_space.seed(seed)

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        if seed is None:
            seed, self._pending_seed = self._pending_seed, None
        else:
            self._pending_seed = None
        return self.env.reset(seed=seed, options=options)

