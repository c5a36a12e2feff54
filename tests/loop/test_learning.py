"""Learning test: VSG must solve a tiny pixel reach task clearly better than a random policy.

The task (built here, for this test, deterministic): a 64x64 RGB image shows a red square (the
agent, starting at the centre) and a green square (the target, always at ``TARGET``). A 2-D
action in [-1, 1]^2 moves the agent by ``SPEED`` per step; the reward is the negative distance
to the target (times ``REWARD_SCALE``), every step, for ``EPISODE`` steps. The agent's final
evaluation score (``EVAL_EPISODES`` episodes) is compared with a uniform random policy and with
an oracle that moves straight to the target: it must close at least half of the gap between
them. Measured (seed 0): VSG -16.3, random -42.6, oracle -1.9, threshold -22.3.

Setting ``VSGJAX_BREAK_ACTOR_GRAD=1`` runs the same test with the actor's loss wrapped in
``stop_gradient`` (the actor never learns; the ``actor_learns`` fixture of conftest.py); the
test must then FAIL, which shows that it measures learning. Measured: -65.5 with the broken
gradient, so it fails as it should.
"""

from __future__ import annotations

import functools
import json

import gymnasium
import numpy as np
import pytest

from vsgjax.config import make_config
from vsgjax.data.collect import EnvBatch
from vsgjax.envs.wrappers import DefaultSeed
from vsgjax.loop.host_trainer import HostTrainer

SIZE = 64
DOT = 10  # square side in pixels
TARGET = np.array([0.15, 0.15])
REWARD_SCALE = 4.0  # reward = -REWARD_SCALE * distance
SPEED = 0.12  # agent displacement per unit action, in arena units ([0, 1]^2)
EPISODE = 20  # agent steps per episode
EVAL_EPISODES = 3
SEED = 0

# Small VSG: debug-sized pieces, short sequences, fast learning rates; 600 updates.
OVERRIDES = [
    "env.action_repeat=1", "env.time_limit=20",
    "model.deter=64", "model.hidden=64", "model.stoch=8", "model.classes=8",
    "wm.cnn_depth=8", "wm.mlp_layers=2", "wm.mlp_units=64", "wm.reward_layers=2",
    "wm.lr=1e-3", "ac.actor_lr=5e-4", "ac.critic_lr=5e-4",
    "ac.actor_layers=2", "ac.critic_layers=2", "ac.horizon=10",
    "train.batch=8", "train.length=10", "train.train_every=2", "train.prefill=200",
    "train.steps=1400", "train.eval_every=400", f"train.eval_episodes={EVAL_EPISODES}",
    "train.log_every=200", "train.ckpt_every=100000", "train.video_every=100000",
]


class ReachEnv(gymnasium.Env):
    """Move the red square to the green one; reward −distance per step (module docstring)."""

    def __init__(self):
        self.observation_space = gymnasium.spaces.Box(0, 255, (SIZE, SIZE, 3), np.uint8)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.agent = np.full(2, 0.5)
        self.target = np.full(2, 0.5)
        self.t = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.agent = np.full(2, 0.5)
        self.target = TARGET
        self.t = 0
        return self._image(), {}

    def step(self, action):
        self.agent = np.clip(self.agent + SPEED * np.clip(action, -1, 1), 0.0, 1.0)
        self.t += 1
        reward = -REWARD_SCALE * float(np.linalg.norm(self.agent - self.target))
        return self._image(), reward, False, self.t >= EPISODE, {}

    def _image(self) -> np.ndarray:
        image = np.zeros((SIZE, SIZE, 3), np.uint8)
        for position, channel in ((self.target, 1), (self.agent, 0)):
            x, y = np.round(position * (SIZE - DOT)).astype(int)
            image[y:y + DOT, x:x + DOT, channel] = 255
        return image


def make_reach_env(seed: int) -> gymnasium.Env:
    """A reach env whose first reset uses ``seed`` (later resets continue its generator)."""
    return DefaultSeed(ReachEnv(), seed)


def reach_envs(env_cfg, seed: int, num_envs: int, *, eval: bool = False) -> EnvBatch:
    """The Trainer's env factory for this task (eval envs on seeds disjoint from training)."""
    base = seed + 1000 if eval else seed
    return EnvBatch([functools.partial(make_reach_env, base + i) for i in range(num_envs)],
                    workers=False)


def baseline_return(policy, episodes: int, seed: int) -> float:
    """Mean return of ``policy(env, rng) -> action`` on fresh reach episodes."""
    rng, env, returns = np.random.default_rng(seed), ReachEnv(), []
    for episode in range(episodes):
        env.reset(seed=seed + episode)
        total, done = 0.0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(policy(env, rng))
            total, done = total + reward, terminated or truncated
        returns.append(total)
    return float(np.mean(returns))


def random_action(env: ReachEnv, rng: np.random.Generator) -> np.ndarray:
    return rng.uniform(-1, 1, 2)


def oracle_action(env: ReachEnv, rng: np.random.Generator) -> np.ndarray:
    return np.clip((env.target - env.agent) / SPEED, -1, 1)


def test_oracle_beats_random_by_a_wide_margin():
    random_score = baseline_return(random_action, 200, SEED)
    oracle_score = baseline_return(oracle_action, 200, SEED)
    assert oracle_score > random_score + 3.0 * REWARD_SCALE, (oracle_score, random_score)


def test_reach_images_show_both_dots():
    env = ReachEnv()
    image, _ = env.reset(seed=3)
    assert image[..., 0].sum() == 255 * DOT * DOT and image[..., 1].sum() == 255 * DOT * DOT
    image, *_ = env.step(np.array([1.0, 0.0], np.float32))
    x = np.flatnonzero(image[..., 0].any(0))[0]
    assert x == round((0.5 + SPEED) * (SIZE - DOT))


@pytest.mark.slow
def test_vsg_learns_to_reach(tmp_path, actor_learns):
    config = make_config("dmc_reach", "vsg", "debug", OVERRIDES)
    trainer = HostTrainer(config, tmp_path, make_envs=reach_envs, progress=False)
    try:
        assert trainer.run() == 0
    finally:
        trainer.close()
    scores = json.loads((tmp_path / "scores.jsonl").read_text())
    random_score = baseline_return(random_action, 200, SEED)
    oracle_score = baseline_return(oracle_action, 200, SEED)
    threshold = random_score + 0.5 * (oracle_score - random_score)
    print(f"reach: eval returns {scores['ys']} at {scores['xs']}; random {random_score:.2f}, "
          f"oracle {oracle_score:.2f}, threshold {threshold:.2f}")
    assert scores["ys"][-1] > threshold, (scores, random_score, oracle_score)
