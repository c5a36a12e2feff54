"""MJX device-loop test: VSG at the cpu size must swing the cartpole to twice random.

``mjx_cartpole_swingup`` (dm_control's task on MJX, 1000 env steps per episode, action repeat
2), VSG at the ``cpu`` size with its own prefill (4,000 env steps) and pretraining (100
updates), stopped at 8,000 env steps: 600 updates in one process with the fully jitted loop.
The final evaluation (4 episodes, the actor's mode) must reach twice the mean return of a
uniform random policy (32 episodes), which is above DreamerV3's mean at its first logged point
(20k env steps: 63). Measured (seed 0, this 2-core CPU): random 45.8, threshold 91.5,
evaluations 151.6 / 173.9 at 6k / 8k env steps (166.6 at 12k), the first env steps of the
committed 100k-step run (experiments/results/cpu_proprio).

What this does not show: that the actor learns. With the actor's gradient cut
(``VSGJAX_BREAK_ACTOR_GRAD=1``, conftest.py) the same run scores 192.6 / 159.0 (168.5 at 12k): this
early the untrained actor's mode, a fixed random function of the world model's learned
features, swings the pole as well as the trained one (DreamerV3's own curve is near random
here too). The actor's learning is shown by the pixel reach test (tests/loop/test_learning.py)
and by the committed 100k-step runs (654 at 100k env steps against DreamerV3's 322).
"""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from vsgjax.config import make_config
from vsgjax.envs.mjx import make_mjx_task
from vsgjax.envs.mjx.random_policy import random_returns
from vsgjax.train import make_trainer

TASK, SEED, RANDOM_EPISODES = "mjx_cartpole_swingup", 0, 32
OVERRIDES = ["train.steps=8000", "train.eval_every=4000", "train.ckpt_every=1000000"]


def random_mean(config) -> float:
    task = make_mjx_task(TASK, config.env.action_repeat, config.env.time_limit)
    return float(np.mean(random_returns(task, RANDOM_EPISODES, jax.random.PRNGKey(SEED))))


@pytest.mark.slow
def test_the_device_loop_swings_the_cartpole_to_twice_random(tmp_path):
    config = make_config(TASK, "vsg", "cpu", [f"train.seed={SEED}", *OVERRIDES])
    trainer = make_trainer([config], [tmp_path], progress=False)
    try:
        assert trainer.run() == 0
    finally:
        trainer.close()
    scores = json.loads((tmp_path / "scores.jsonl").read_text())
    random_score = random_mean(config)
    threshold = 2.0 * random_score
    print(f"{TASK}: eval returns {scores['ys']} at {scores['xs']}; random {random_score:.1f}, "
          f"threshold {threshold:.1f}")
    assert scores["xs"][-1] == 8_000
    assert scores["ys"][-1] > threshold, (scores, random_score)
