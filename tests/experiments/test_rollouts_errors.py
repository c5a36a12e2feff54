"""``experiments.rollouts`` writes the open-loop errors of the samples it draws: a fresh debug
DreamerV2 (pixels) and one stored 50-step episode whose brightness changes with the step, so
that an error compared against the wrong step shows."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from experiments import rollouts
from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.config import make_config, to_dict
from vsgjax.data import checkpoint
from vsgjax.data.replay import EpisodeStore
from vsgjax.loop.run_state import checkpoint_tree


@pytest.mark.slow
def test_rollouts_write_the_errors_of_the_samples_they_draw(tmp_path):
    config = make_config("bbs_basic", "dreamerv2", "debug")
    logdir = tmp_path / "run"
    (logdir / "config.json").parent.mkdir(parents=True)
    (logdir / "config.json").write_text(json.dumps(to_dict(config)))
    key = jax.random.PRNGKey(0)
    state = DreamerAgent(config, (64, 64, 3), 2, False).init(key)
    checkpoint.save(logdir / "checkpoints", 0, checkpoint_tree(state, key))
    steps = 50
    rng = np.random.default_rng(0)
    action = rng.uniform(-1, 1, (steps, 2)).astype(np.float32)
    action[0] = 0
    episode = {"image": np.repeat(np.arange(steps, dtype=np.uint8)[:, None, None, None] * 5,
                                  64 * 64 * 3).reshape(steps, 64, 64, 3),
               "action": action, "reward": rng.normal(size=steps).astype(np.float32),
               "is_first": np.arange(steps) == 0, "is_terminal": np.zeros(steps, bool)}
    episode["reward"][0] = 0
    EpisodeStore(logdir / "episodes").write(episode)
    said = []
    data, written = rollouts.make_rollouts(logdir, tmp_path / "out", samples=2, say=said.append)
    assert data.obs_mse.shape == data.reward_mse.shape == (35,)
    # the samples' own imagined frames (uint8) against the truth of the same steps
    truth = data.frames[0, 15:].astype(np.float64) / 255
    drawn = data.frames[1:, 15:].astype(np.float64) / 255
    np.testing.assert_allclose(data.obs_mse, ((drawn - truth) ** 2).mean((0, 2, 3, 4)),
                               rtol=0.02, atol=2e-5)
    np.testing.assert_allclose(data.reward_mse,
                               ((data.rewards[1:, 15:] - data.rewards[0, 15:]) ** 2).mean(0),
                               rtol=1e-4)
    saved = np.load(tmp_path / "out" / "rollouts-ep0.npz")
    np.testing.assert_array_equal(saved["obs_mse"], data.obs_mse)
    line = next(text for text in said if text.startswith("open-loop MSE"))
    assert f"35: obs {data.obs_mse[34]:.4g}" in line
