"""Learning test: VSG must solve a tiny pixel reach task that cannot be solved without seeing.

The task (built here, for this test): a 64x64 RGB image shows a red square (the agent, starting
at the centre) and a green square (the target, at one of the two top ``CORNERS``, drawn per
training episode from the env's seeded generator; the evaluation envs alternate between them,
so every evaluation of an even number of episodes sees each corner equally often). A 2-D action
in [-1, 1]^2 moves the agent by ``SPEED`` per step; the reward is the negative distance to the
target (times ``REWARD_SCALE``), every step, for ``EPISODE`` steps. Since the target moves
between episodes, no constant action reaches it: the best constant action (searched on a grid,
measured here) goes up between the corners. The agent's final evaluation (``EVAL_EPISODES``
episodes) must close ``MARGIN`` of the gap between that best constant action and an oracle that
moves straight to the target.

Two switches run the same test with a part of the agent broken; the test must then FAIL, which
shows that it measures learning from what the agent sees:

* ``VSGJAX_BREAK_ACTOR_GRAD=1``: the actor's loss is wrapped in ``stop_gradient`` (the
  ``actor_learns`` fixture of conftest.py);
* ``VSGJAX_BREAK_PERCEPTION=1``: the encoder's embedding is multiplied by zero, so the world
  model and the policy never see the image (the ``perception_works`` fixture).

The measured scores are in docs/training.md ("Learning test").
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
DOT = 10  # the agent's side in pixels
CORNERS = np.array([[0.15, 0.15], [0.85, 0.15]])
TARGET_DOT = 24  # the target's side in pixels: large enough to be seen within the test's updates
REWARD_SCALE = 4.0  # reward = -REWARD_SCALE * distance
SPEED = 0.12  # agent displacement per unit action, in arena units ([0, 1]^2)
EPISODE = 20  # agent steps per episode
EVAL_EPISODES = 8  # even: each corner 4 times
MARGIN = 0.25  # the share of the gap from the best constant action to the oracle to close
SEED = 0

# Small VSG: debug-sized pieces, short sequences, fast learning rates; 900 updates.
OVERRIDES = [
    "env.action_repeat=1", "env.time_limit=20",
    "model.deter=64", "model.hidden=64", "model.stoch=8", "model.classes=8",
    "wm.cnn_depth=8", "wm.mlp_layers=2", "wm.mlp_units=64", "wm.reward_layers=2",
    "wm.lr=1e-3", "ac.actor_lr=5e-4", "ac.critic_lr=5e-4",
    "ac.actor_layers=2", "ac.critic_layers=2", "ac.horizon=10",
    "train.batch=8", "train.length=10", "train.train_every=2", "train.prefill=200",
    "train.steps=2000", "train.eval_every=500", f"train.eval_episodes={EVAL_EPISODES}",
    "train.log_every=200", "train.ckpt_every=100000", "train.video_every=100000",
]


def move(agent: np.ndarray, action: np.ndarray) -> np.ndarray:
    """The agent's next position: one step of ``SPEED`` per unit action, inside [0, 1]^2."""
    return np.clip(agent + SPEED * np.clip(action, -1, 1), 0.0, 1.0)


def reward_at(agent: np.ndarray, target: np.ndarray) -> np.ndarray:
    return -REWARD_SCALE * np.linalg.norm(agent - target, axis=-1)


class ReachEnv(gymnasium.Env):
    """Move the red square to the green one, which sits at a corner drawn per episode (or, with
    ``alternate``, the corners in turn); reward −distance per step (module docstring)."""

    def __init__(self, alternate: bool = False):
        self.alternate, self.resets = alternate, 0
        self.observation_space = gymnasium.spaces.Box(0, 255, (SIZE, SIZE, 3), np.uint8)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
        self.agent = np.full(2, 0.5)
        self.target = np.full(2, 0.5)
        self.t = 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.agent = np.full(2, 0.5)
        index = self.resets if self.alternate else self.np_random.integers(len(CORNERS))
        self.target, self.resets = CORNERS[index % len(CORNERS)], self.resets + 1
        self.t = 0
        return self._image(), {}

    def step(self, action):
        self.agent = move(self.agent, action)
        self.t += 1
        reward = float(reward_at(self.agent, self.target))
        return self._image(), reward, False, self.t >= EPISODE, {}

    def _image(self) -> np.ndarray:
        image = np.zeros((SIZE, SIZE, 3), np.uint8)
        for position, channel, side in ((self.target, 1, TARGET_DOT), (self.agent, 0, DOT)):
            x, y = np.round(position * (SIZE - side)).astype(int)
            image[y:y + side, x:x + side, channel] = 255
        return image


def make_reach_env(seed: int, alternate: bool = False) -> gymnasium.Env:
    """A reach env whose first reset uses ``seed`` (later resets continue its generator)."""
    return DefaultSeed(ReachEnv(alternate), seed)


def reach_envs(env_cfg, seed: int, num_envs: int, *, eval: bool = False) -> EnvBatch:
    """The Trainer's env factory for this task (eval envs on seeds disjoint from training)."""
    base = seed + 1000 if eval else seed
    return EnvBatch([functools.partial(make_reach_env, base + i, eval)
                     for i in range(num_envs)], workers=False)


def episode_returns(policy) -> np.ndarray:
    """The return of ``policy(agent, target) -> action`` from the centre to each corner (the
    evaluation's mean: it sees the corners equally often)."""
    agent, returns = np.full((len(CORNERS), 2), 0.5), np.zeros(len(CORNERS))
    for _ in range(EPISODE):
        agent = move(agent, policy(agent, CORNERS))
        returns += reward_at(agent, CORNERS)
    return returns


def oracle_return() -> float:
    """Mean return of moving straight to the target (the corners are equally likely)."""
    return float(episode_returns(lambda agent, target: (target - agent) / SPEED).mean())


def best_constant_action(grid: int = 21) -> tuple[np.ndarray, float]:
    """The constant action with the highest mean return over the corners, on a grid of
    [-1, 1]^2, and that return: the best a policy that does not see the target can do."""
    actions = np.stack(np.meshgrid(*[np.linspace(-1, 1, grid)] * 2), -1).reshape(-1, 2)
    means = [episode_returns(lambda agent, target, a=a: a).mean() for a in actions]
    best = int(np.argmax(means))
    return actions[best], float(means[best])


def test_the_target_varies_and_no_constant_action_reaches_it():
    env, targets = ReachEnv(), set()
    for seed in range(40):
        env.reset(seed=seed)
        targets.add(tuple(env.target))
    assert targets == {tuple(corner) for corner in CORNERS}
    action, constant = best_constant_action()
    assert abs(action[0]) <= 0.1, action  # the corners are symmetric about the centre
    assert oracle_return() > constant + 20.0, (oracle_return(), constant)
    alternating = ReachEnv(alternate=True)
    seen = []
    for _ in range(EVAL_EPISODES):
        alternating.reset()
        seen.append(tuple(alternating.target))
    assert sorted(seen) == sorted([tuple(c) for c in CORNERS] * (EVAL_EPISODES // 2))


def test_reach_images_show_both_dots():
    env = ReachEnv()
    image, _ = env.reset(seed=3)
    assert image[..., 0].sum() == 255 * DOT * DOT
    assert image[..., 1].sum() == 255 * TARGET_DOT * TARGET_DOT
    image, *_ = env.step(np.array([1.0, 0.0], np.float32))
    x = np.flatnonzero(image[..., 0].any(0))[0]
    assert x == round((0.5 + SPEED) * (SIZE - DOT))


@pytest.mark.slow
def test_vsg_learns_to_reach(tmp_path, actor_learns, perception_works):
    config = make_config("dmc_reach", "vsg", "debug", OVERRIDES)
    trainer = HostTrainer(config, tmp_path, make_envs=reach_envs, progress=False)
    try:
        assert trainer.run() == 0
    finally:
        trainer.close()
    scores = json.loads((tmp_path / "scores.jsonl").read_text())
    action, constant = best_constant_action()
    oracle = oracle_return()
    threshold = constant + MARGIN * (oracle - constant)
    print(f"reach: eval returns {scores['ys']} at {scores['xs']}; best constant action "
          f"{action} {constant:.2f}, oracle {oracle:.2f}, threshold {threshold:.2f} "
          f"(actor learns: {actor_learns}, perception works: {perception_works})")
    assert scores["ys"][-1] > threshold, (scores, constant, oracle)
