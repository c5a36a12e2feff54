"""``experiments.reset_state``: the decoder's error from carried and from reset posteriors, on
an untrained debug DreamerV2 (vector observations) standing in for a loaded run."""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import jax
import numpy as np
import pytest

from experiments import reset_state
from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.config import make_config
from vsgjax.episode_keys import VECTOR_KEY

TASK = "mjx_pendulum_swingup"


def episode(seed: int, length: int = 9) -> dict:
    rng = np.random.default_rng(seed)
    return {VECTOR_KEY: rng.normal(size=(length, 3)).astype(np.float32),
            "action": rng.uniform(-1, 1, (length, 1)).astype(np.float32),
            "reward": np.zeros(length, np.float32), "is_first": np.eye(1, length, dtype=bool)[0]}


def fake_run(spec: dict, episodes: list[dict]) -> SimpleNamespace:
    config = make_config(TASK, "dreamerv2", "debug")
    agent = DreamerAgent(config, spec, 1, False)
    params = agent.init(jax.random.PRNGKey(0)).params
    return SimpleNamespace(world_model=agent.world_model, params=SimpleNamespace(wm=params["wm"]),
                           config=config, logdir=Path("runs/fake"),
                           episodes=lambda limit: episodes[-limit:])


def test_fractions_cover_each_dimension_after_the_first_steps_and_repeat_with_the_seed():
    episodes = [episode(0), episode(1), episode(2)]
    run = fake_run({VECTOR_KEY: (3,)}, episodes)
    fractions = reset_state.unexplained_fractions(run, episodes=2, seed=3)
    later = np.concatenate([e[VECTOR_KEY][1:] for e in episodes[1:]])
    np.testing.assert_allclose(fractions["variance"], later.var(0), rtol=1e-6)
    for name in reset_state.STATES:
        assert fractions[name].shape == (3,) and np.all(np.isfinite(fractions[name]))
        assert np.all(fractions[name] > 0)
    again = reset_state.unexplained_fractions(run, episodes=2, seed=3)
    for name in reset_state.STATES:
        np.testing.assert_array_equal(fractions[name], again[name])


def test_an_image_run_or_a_missing_one_is_refused_naming_it(tmp_path, capsys):
    run = fake_run({"image": (64, 64, 3)}, [])
    with pytest.raises(ValueError, match="runs/fake observes .*vector observations only"):
        reset_state.unexplained_fractions(run, episodes=1)
    assert reset_state.main([str(tmp_path / "no_such_run")]) == 2
    assert "no_such_run" in capsys.readouterr().err
    assert reset_state.main([str(tmp_path), "--episodes", "0"]) == 2
    assert "--episodes 0; valid: >= 1" in capsys.readouterr().err
