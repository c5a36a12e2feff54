"""A cheap deterministic image env for tests and benchmarks (not part of the task scheme).

Each episode lasts ``length + U{0, 1, 2}`` agent steps (drawn from the reset seed's RNG), then
terminates (or is truncated when ``terminate=False``). The image is filled with the step count,
and its first pixel encodes the last action, so recorded streams reveal any misalignment. The
reward is the sum of the continuous action, or the discrete action's index.
"""

from __future__ import annotations

import gymnasium
import numpy as np


class FakeImageEnv(gymnasium.Env):
    def __init__(self, *, length: int = 5, terminate: bool = True, action_dim: int = 2,
                 discrete: bool = False, size: int = 64, channels: int = 3):
        self.observation_space = gymnasium.spaces.Box(0, 255, (size, size, channels), np.uint8)
        if discrete:
            self.action_space = gymnasium.spaces.Discrete(action_dim)
        else:
            self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (action_dim,), np.float32)
        self._base_length, self._terminate, self._discrete = length, terminate, discrete
        self._t, self._length = 0, length

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        self._t = 0
        self._length = self._base_length + int(self.np_random.integers(0, 3))
        return self._image(0.0), {}

    def step(self, action):
        self._t += 1
        value = float(action) if self._discrete else float(np.sum(action))
        done = self._t >= self._length
        info = {"fake_metric": float(self._t)} if done else {}
        return (self._image(value), value, done and self._terminate,
                done and not self._terminate, info)

    def _image(self, action_value: float) -> np.ndarray:
        image = np.full(self.observation_space.shape, self._t % 256, np.uint8)
        image[0, 0, 0] = int(round(action_value * 50)) % 256
        return image
