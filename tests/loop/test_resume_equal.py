"""A run stopped by SIGINT and resumed, against the same run uninterrupted (CPU, same seed).

The device loop's uninterrupted run also checks its ``gates/*`` lines (tests/support/gate_lines.py).

The device loop's checkpoint holds its whole state (agent, device replay, PRNG key) and each
of its calls starts by resetting the envs, so the resumed run must reach the uninterrupted
run's state, training metrics and scores exactly. The host loop's envs are not checkpointed:
a resumed run drops the unfinished episodes and reseeds its training envs
(``schedule.env_seed``), so its data differ after a resume; what it restores must be exactly
what the stopped run held: parameters, optimiser state, PRNG keys, replay contents and RNG,
counters and scores.
"""

from __future__ import annotations

import dataclasses
import json
import signal
from pathlib import Path

import jax
import numpy as np
import pytest

from tests.support.gate_lines import check_equals_loaded, check_lines, gate_lines
from vsgjax.config import make_config
from vsgjax.data import checkpoint
from vsgjax.loop.device_trainer import DeviceTrainer
from vsgjax.loop.host_trainer import HostTrainer

# mjx_cartpole_balance: 80 env steps per call (prefill, then 2 pretraining + 4 updates a call)
DEVICE = ["env.time_limit=40", "env.num_envs=2", "train.length=8", "train.batch=3",
          "train.train_every=5", "train.prefill=80", "train.pretrain=2", "train.steps=320",
          "train.eval_every=80", "train.ckpt_every=100"]
# bbs_basic: 200-step episodes, prefill ends at 208 env steps, chunks of 16 env steps
HOST = ["env.time_limit=200", "train.eval_every=100000", "train.video_every=100000",
        "train.train_every=4", "train.steps=320"]
SIGINT_EXIT = 128 + signal.SIGINT
CLOCKS = ("wall_s", "cpu_s", "steps_per_s")  # record keys ending so differ between runs


def stop_at(trainer, env_steps: int) -> None:
    """Send ``trainer`` SIGINT once it has reached ``env_steps`` (in the middle of its loop)."""
    step = trainer.step

    def step_then_stop():
        step()
        if trainer.env_steps >= env_steps and not trainer.stopped_by_test:
            trainer.stopped_by_test = True
            signal.raise_signal(signal.SIGINT)

    trainer.stopped_by_test = False
    trainer.step = step_then_stop


def run(trainer) -> int:
    try:
        return trainer.run()
    finally:
        trainer.close()


def assert_trees_equal(a, b) -> None:
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def records(logdir: Path) -> list[dict]:
    lines = (logdir / "metrics.jsonl").read_text().splitlines()
    return [{k: v for k, v in json.loads(line).items() if not k.endswith(CLOCKS)}
            for line in lines]


def scores(logdir: Path) -> tuple[list, list]:
    record = json.loads((logdir / "scores.jsonl").read_text())
    return record["xs"], record["ys"]


@pytest.mark.slow
def test_device_loop_stopped_and_resumed_equals_the_uninterrupted_run(tmp_path):
    config = make_config("mjx_cartpole_balance", "vsg", "debug", DEVICE)
    trainer = lambda logdir: DeviceTrainer([config], [logdir], progress=False,
                                           out=lambda *_: None)
    whole = trainer(tmp_path / "whole")
    assert run(whole) == 0
    stopped = trainer(tmp_path / "parts")
    stop_at(stopped, 160)  # after the first training call
    assert run(stopped) == SIGINT_EXIT and stopped.env_steps == 160
    resumed = trainer(tmp_path / "parts")
    assert resumed.resumed and resumed.env_steps == 160
    assert run(resumed) == 0
    assert_trees_equal(resumed.state, whole.state)  # agent, optimiser, device replay, key
    assert dataclasses.replace(resumed.counters, wall_s=0, cpu_s=0, last_ckpt_updates=0,
                               last_ckpt_step=0) == \
        dataclasses.replace(whole.counters, wall_s=0, cpu_s=0, last_ckpt_updates=0,
                            last_ckpt_step=0)
    xs, ys = scores(tmp_path / "whole")
    assert xs == [160, 240, 320] and scores(tmp_path / "parts") == (xs, ys)
    assert records(tmp_path / "parts") == records(tmp_path / "whole")  # train/*, gates/*, ...
    lines = gate_lines(tmp_path / "whole")  # a log per call: the last at the final checkpoint
    check_lines(lines, final_step=320, first_step=160)
    batch = whole.gate_batch(0)
    assert np.asarray(batch["is_first"]).shape == (3, 8)
    check_equals_loaded(tmp_path / "whole", lines[-1], batch)


@pytest.mark.slow
def test_host_loop_resumes_exactly_the_state_it_stopped_with(tmp_path):
    config = make_config("bbs_basic", "vsg", "debug", HOST)
    stopped = HostTrainer(config, tmp_path, progress=False, out=lambda *_: None)
    stop_at(stopped, 240)
    assert run(stopped) == SIGINT_EXIT and stopped.counters.updates > 2
    resumed = HostTrainer(config, tmp_path, progress=False, out=lambda *_: None)
    try:
        assert resumed.resumed
        assert_trees_equal(resumed.state, stopped.state)  # parameters, optimiser, step
        assert_trees_equal(resumed.keys, stopped.keys)
        assert resumed.counters == stopped.counters
        assert resumed.runs[0].scores == stopped.runs[0].scores
        assert resumed.runs[0].episodes == stopped.runs[0].episodes
        before, after = stopped.runs[0].replay, resumed.runs[0].replay
        assert checkpoint.rng_state(after.rng) == checkpoint.rng_state(before.rng)
        assert (after.num_steps, after.num_episodes) == (before.num_steps, before.num_episodes)
        assert_trees_equal(after.sample(8), before.sample(8))  # same contents, same draws
    finally:
        resumed.close()
