"""The ``gates/*`` lines both training loops log (vsgjax/loop/gate_logging.py).

Each loop trains a debug VSG with a log at every iteration, so that its last ``gates/*`` line
is written at the step of its final checkpoint; the statistics of that checkpoint, loaded with
``vsgjax.load``, on the batch the line was computed on, must be the logged ones.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

import vsgjax
from vsgjax.config import make_config
from vsgjax.loop.device_trainer import DeviceTrainer
from vsgjax.loop.host_trainer import HostTrainer
from vsgjax.loop.parallel import take

# bbs_basic: 200-step episodes, prefill ends at 208 env steps, chunks of 16 env steps
HOST = ["env.time_limit=200", "train.eval_every=100000", "train.video_every=100000",
        "train.train_every=4", "train.log_every=16", "train.steps=256"]
# mjx_cartpole_balance: 80 env steps per call, 4 updates per call once trained
DEVICE = ["env.time_limit=40", "env.num_envs=2", "train.length=8", "train.batch=3",
          "train.train_every=5", "train.prefill=80", "train.pretrain=2", "train.steps=240"]
SUMMARY_KEYS = {"gates/open", "gates/open_prior", "gates/prob_post", "gates/prob_prior",
                "gates/kl", "gates/open_per_step_std", "gates/open_per_unit_std",
                "gates/never_open", "gates/always_open", "gates/closed_run_mean"}


def gate_lines(logdir: Path) -> list[dict]:
    records = map(json.loads, (logdir / "metrics.jsonl").read_text().splitlines())
    return [r for r in records if any(key.startswith("gates/") for key in r)]


def train(trainer) -> None:
    try:
        assert trainer.run() == 0
    finally:
        trainer.close()


def check_lines(lines: list[dict], final_step: int, first_step: int) -> None:
    """One line per log from the first training log to the end, every value a fraction
    (the KL and the run length excepted) and not constant."""
    steps = [line["step"] for line in lines]
    assert steps[0] == first_step and steps[-1] == final_step and steps == sorted(set(steps))
    for line in lines:
        assert set(line) == {"step", *SUMMARY_KEYS}
        fractions = [v for k, v in line.items() if k not in ("step", "gates/kl",
                                                             "gates/closed_run_mean")]
        assert all(0.0 <= v <= 1.0 for v in fractions), line
        assert 0 < line["gates/open"] < 1 and line["gates/kl"] > 0
        assert line["gates/closed_run_mean"] >= 1
    assert len({line["gates/kl"] for line in lines}) > 1  # the model changes between logs


def check_equals_loaded(logdir: Path, line: dict, batch: dict) -> None:
    run = vsgjax.load(logdir)
    assert run.step == line["step"]
    stats = vsgjax.gate_statistics(run.params, batch).summary()
    assert stats == pytest.approx({k: v for k, v in line.items() if k != "step"},
                                  rel=1e-6, abs=1e-7)


@pytest.mark.slow
def test_host_loop_logs_the_gate_statistics_of_its_checkpoints(tmp_path):
    config = make_config("bbs_basic", "vsg", "debug", HOST)
    trainer = HostTrainer(config, tmp_path, progress=False, out=lambda *_: None)
    train(trainer)
    lines = gate_lines(tmp_path)
    check_lines(lines, final_step=256, first_step=208)
    check_equals_loaded(tmp_path, lines[-1], take(trainer.last_batch, 0))


@pytest.mark.slow
def test_device_loop_logs_the_gate_statistics_of_its_checkpoints(tmp_path):
    config = make_config("mjx_cartpole_balance", "vsg", "debug", DEVICE)
    trainer = DeviceTrainer([config], [tmp_path], progress=False, out=lambda *_: None)
    train(trainer)
    lines = gate_lines(tmp_path)
    check_lines(lines, final_step=240, first_step=160)
    batch = trainer.gate_batch(0)
    assert np.asarray(batch["is_first"]).shape == (3, 8)
    check_equals_loaded(tmp_path, lines[-1], batch)
