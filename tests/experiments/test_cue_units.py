"""Tests of ``python -m experiments.cue_units``: its measurements on states and gates built by
hand, end to end on a tiny trained VSG run, and bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest

from experiments import cue_units
from tests.loop.test_gymnax_device_loop import SHORT, TASK
from tests.loop.test_resume_equal import run
from vsgjax.config import make_config
from vsgjax.loop.device_trainer import DeviceTrainer

LENGTH, EPISODES = 6, 400


def hand_made(seed: int = 0):
    """``(state, cue, gate)`` ``[B, L + 2, 4]`` of four kinds of unit:

    0. written at step 1 only under cue +1 (its gate opens there only then), closed after:
       a cue unit, held, cue-gated;
    1. open at every step, its state the cue from step 1 on: a cue unit, not held;
    2. open at random (0.3), its state noise: neither;
    3. never open, constant: held, no cue unit.
    """
    rng = np.random.default_rng(seed)
    cue = rng.choice([-1.0, 1.0], EPISODES)
    steps = LENGTH + 2
    gate = np.zeros((EPISODES, steps, 4))
    gate[:, 1, 0] = cue > 0
    gate[:, :, 1] = 1
    gate[:, :, 2] = rng.random((EPISODES, steps)) < 0.3
    state = 0.1 * rng.standard_normal((EPISODES, steps, 4))
    state[:, 1:, 0] += (cue > 0)[:, None]
    state[:, 1:, 1] += cue[:, None]
    state[:, :, 3] = 0.5
    return state, cue, gate


def test_a_unit_written_under_one_cue_and_held_is_found():
    state, cue, gate = hand_made()
    record = cue_units.measure(state, cue, LENGTH, gate)
    assert record["cue_units"] == 2 and record["cue_units_held"] == 1
    assert record["units_held"] == 2  # the written unit and the one that never opens
    assert record["cue_gated_units"] == 1 and record["cue_gate_gap_max"] == 1.0
    assert record["null_cue_gate_gap_max"] < 0.2  # shuffled cues: the gates ignore them
    assert record["readout_all"] == 1.0 and record["readout_held"] == 1.0
    rows = {row["unit"]: row for row in record["units"]}
    assert rows[0]["first_step"] == 1 and rows[0]["held"] == 1.0
    assert rows[0]["open_step1"] == [1.0, 0.0] and rows[0]["open_step2"] == [0.0, 0.0]
    assert rows[1]["held"] == 0.0 and rows[1]["open_step1"] == [1.0, 1.0]
    assert rows[3]["dprime"] == 0.0 and rows[3]["first_step"] is None
    assert 0 < record["open"] < 1


def test_without_gates_only_the_state_is_measured():
    state, cue, _ = hand_made()
    record = cue_units.measure(state, cue, LENGTH, None)
    assert record["cue_units"] == 2 and record["readout_all"] == 1.0
    assert "cue_units_held" not in record and "open_step1" not in record["units"][0]


def test_gates_that_ignore_the_cue_are_not_cue_gated():
    state, cue, gate = hand_made()
    gate[:, 1, 0] = np.random.default_rng(1).random(EPISODES) < 0.5  # opens at random
    record = cue_units.measure(state, cue, LENGTH, gate)
    assert record["cue_gated_units"] == 0
    assert record["cue_gate_gap_max"] < 0.2 and record["null_cue_gate_gap_max"] < 0.2


def test_a_readout_without_units_is_none_and_a_shuffled_cue_is_at_chance():
    state, cue, _ = hand_made()
    assert cue_units.readout_accuracy(state[:, LENGTH], cue, np.array([], int)) is None
    shuffled = np.random.default_rng(2).permutation(cue)
    assert abs(cue_units.readout_accuracy(state[:, LENGTH], shuffled, np.arange(4)) - 0.5) < 0.1


@pytest.mark.slow
def test_a_trained_run_is_measured_and_reported(tmp_path):
    config = make_config(TASK, "vsg", "debug", SHORT)
    trainer = DeviceTrainer([config], [tmp_path / "runs" / "vsg-L3" / "s0"], progress=False,
                            out=lambda *_: None)
    assert run(trainer) == 0
    out = tmp_path / "cue"
    args = [str(tmp_path / "runs" / "vsg-L3" / "s0"), "--episodes", "32", "--out", str(out)]
    assert cue_units.main(args) == 0
    record = json.loads((out / "vsg-L3-s0.json").read_text())
    assert record["model"] == "vsg" and record["memory_length"] == 3 and record["step"] == 160
    assert 0 <= record["cue_units_held"] <= record["cue_units"] <= 128
    assert 0 <= record["cue_gate_gap_max"] <= 1 and 0 < record["open"] < 1
    assert record["actor_accuracy"] * 32 == round(record["actor_accuracy"] * 32)  # episodes
    assert len(record["units"]) == cue_units.TOP_UNITS
    assert "| vsg-L3-s0 | 3 |" in (out / "report.md").read_text()
    assert cue_units.main(args) == 0  # measured again: the same record
    assert json.loads((out / "vsg-L3-s0.json").read_text()) == record


def test_bad_runs_and_episode_counts_are_refused(tmp_path, capsys):
    assert cue_units.main([str(tmp_path), "--episodes", "2"]) == 2
    assert "--episodes 2; valid: >= 4" in capsys.readouterr().err
    assert cue_units.main([str(tmp_path / "missing")]) == 2
    assert "is not a directory" in capsys.readouterr().err
