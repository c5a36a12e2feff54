"""The ``gates/*`` lines the host loop logs (vsgjax/loop/gate_logging.py).

A debug VSG trains with a log at every iteration, so that its last ``gates/*`` line is written
at the step of its final checkpoint; the statistics of that checkpoint, loaded with
``vsgjax.load``, on the batch the line was computed on, must be the logged ones. The device
loop's lines are checked on the uninterrupted run of tests/loop/test_resume_equal.py.
"""

from __future__ import annotations

import pytest

from tests.support.gate_lines import check_equals_loaded, check_lines, gate_lines
from vsgjax.config import make_config
from vsgjax.loop.host_trainer import HostTrainer
from vsgjax.loop.parallel import take

# bbs_basic: 200-step episodes, prefill ends at 208 env steps, chunks of 16 env steps
HOST = ["env.time_limit=200", "train.eval_every=100000", "train.video_every=100000",
        "train.train_every=4", "train.log_every=16", "train.steps=256"]


def train(trainer) -> None:
    try:
        assert trainer.run() == 0
    finally:
        trainer.close()


@pytest.mark.slow
def test_host_loop_logs_the_gate_statistics_of_its_checkpoints(tmp_path):
    config = make_config("bbs_basic", "vsg", "debug", HOST)
    trainer = HostTrainer(config, tmp_path, progress=False, out=lambda *_: None)
    train(trainer)
    lines = gate_lines(tmp_path)
    check_lines(lines, final_step=256, first_step=208)
    check_equals_loaded(tmp_path, lines[-1], take(trainer.last_batch, 0))
