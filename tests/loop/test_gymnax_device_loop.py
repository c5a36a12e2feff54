"""The device loop on a family whose episodes end before a training sequence is full
(gymnax_memory_len, vsgjax/loop/device_program.py): rows of K episodes, resets inside the
compiled call, sequences across episode boundaries; and end to end, VSG and DreamerV2 train,
evaluate and resume in it.

Memory length 3: episodes of 4 agent steps (5 stored); train.length=8 and train_every=5 make
K = 2 episodes a call (8 agent steps, 1 update), 16 env steps a call with 2 envs.
"""

from __future__ import annotations

import dataclasses
import json

import jax
import numpy as np
import pytest

from tests.loop.test_resume_equal import SIGINT_EXIT, assert_trees_equal, records, run, stop_at
from tests.support.overrides import replaced
from vsgjax import evaluate
from vsgjax.config import make_config
from vsgjax.envs import make_device_task
from vsgjax.episode_keys import VECTOR_KEY
from vsgjax.loop.device_program import DeviceProgram
from vsgjax.loop.device_trainer import DeviceTrainer

TASK = "gymnax_memory_len"
SHORT = ["env.memory_length=3", "env.num_envs=2", "train.length=8", "train.batch=3",
         "train.train_every=5", "train.prefill=32", "train.pretrain=2", "train.steps=160",
         "train.eval_every=48", "train.eval_episodes=8", "train.ckpt_every=100",
         "train.log_every=16"]  # a train record per call: the resumed run logs the same windows


def make_program(*overrides: str, model: str = "vsg") -> DeviceProgram:
    config = make_config(TASK, model, "debug", replaced(SHORT, *overrides))
    program = DeviceProgram(config, make_device_task(config.env))
    program.check()
    return program


@pytest.fixture(scope="module")
def program() -> DeviceProgram:
    return make_program()


@pytest.fixture(scope="module")
def prefill_call(program):
    """(state after, records) of one jitted prefill call."""
    state = program.init(jax.random.PRNGKey(0))
    after, metrics, records = jax.jit(lambda s: program.episode(s, False))(state)
    assert metrics == {}
    return after, jax.device_get(records)


def test_a_call_holds_the_episodes_one_sequence_and_one_update_need(program):
    assert (program.episode_steps, program.episodes_per_call, program.row_steps) == (4, 2, 10)
    assert (program.updates_per_call, program.env_steps_per_call) == (1, 16)
    assert program.spec.discrete and program.spec.action_dim == 2
    # a sequence of 20 steps: 4 episodes; an update every 13 agent steps: 4 episodes (16 steps)
    assert make_program("train.length=20").episodes_per_call == 4
    assert make_program("train.train_every=13").episodes_per_call == 4
    assert make_program("train.length=5", "train.train_every=4").episodes_per_call == 1


def test_a_call_records_its_episodes_back_to_back_in_the_host_format(prefill_call):
    after, records = prefill_call
    assert records[VECTOR_KEY].shape == (2, 10, 3) and records["action"].shape == (2, 10, 2)
    starts, ends = np.arange(10) % 5 == 0, np.arange(10) % 5 == 4
    assert (records["is_first"] == starts).all() and (records["is_terminal"] == ends).all()
    assert (records["action"][:, starts] == 0).all()
    np.testing.assert_array_equal(records["action"][:, ~starts].sum(-1), 1)  # one-hot
    assert (records["reward"][:, ~ends] == 0).all()
    assert set(np.abs(records["reward"][:, ends]).ravel()) == {1.0}
    # each episode: its context at its first two steps decides its reward
    context = records[VECTOR_KEY][:, starts, 2]
    np.testing.assert_array_equal(context, records[VECTOR_KEY][:, starts.nonzero()[0] + 1, 2])
    chosen = 2 * records["action"][:, ends].argmax(-1) - 1
    np.testing.assert_array_equal(records["reward"][:, ends], np.where(chosen == context, 1, -1))
    assert int(after.replay.stored) == 1
    np.testing.assert_array_equal(after.replay.data["is_first"][0], records["is_first"])


def test_sequences_cross_episode_boundaries_where_is_first_marks_the_reset(program,
                                                                           prefill_call):
    after, _ = prefill_call
    sample = jax.jit(program.sample)
    crossing = 0
    for seed in range(10):
        batch = jax.device_get(sample(after.replay, jax.random.PRNGKey(seed)))
        assert batch["is_first"].shape == (3, 8)
        crossing += int(batch["is_first"][:, 1:].any(axis=1).sum())
        first = batch["is_first"]
        assert (batch["action"][first] == 0).all() and (batch["reward"][first] == 0).all()
    assert crossing > 0


def test_the_mjx_rows_stay_one_episode():
    config = make_config("mjx_cartpole_balance", "vsg", "debug",
                         ["env.time_limit=40", "train.length=8"])
    program = DeviceProgram(config, make_device_task(config.env))
    assert program.episodes_per_call == 1 and program.row_steps == 21


# --- end to end ----------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("model", ["vsg", "dreamerv2"])
def test_an_agent_trains_evaluates_and_resumes_to_the_uninterrupted_run(model, tmp_path):
    config = make_config(TASK, model, "debug", SHORT)
    trainer = lambda logdir: DeviceTrainer([config], [logdir], progress=False,
                                           out=lambda *_: None)
    whole = trainer(tmp_path / "whole")
    assert run(whole) == 0
    stopped = trainer(tmp_path / "parts")
    stop_at(stopped, 80)
    assert run(stopped) == SIGINT_EXIT and stopped.env_steps == 80
    resumed = trainer(tmp_path / "parts")
    assert resumed.resumed and resumed.env_steps == 80
    assert run(resumed) == 0
    assert_trees_equal(resumed.state, whole.state)  # agent, optimiser, device replay, key
    clocks = dict(wall_s=0, cpu_s=0, last_ckpt_updates=0, last_ckpt_step=0)
    assert dataclasses.replace(resumed.counters, **clocks) == \
        dataclasses.replace(whole.counters, **clocks)
    assert records(tmp_path / "parts") == records(tmp_path / "whole")
    score = json.loads((tmp_path / "whole" / "scores.jsonl").read_text())
    assert len(score["xs"]) >= 2 and score["xs"][-1] == 160  # evaluated, the last at the end
    assert set(np.abs(score["ys"])) <= {0.0, 0.25, 0.5, 0.75, 1.0}  # means of 8 returns ±1
    lines = [json.loads(line) for line in (tmp_path / "whole" / "metrics.jsonl").read_text()
             .splitlines()]
    updates = max(line.get("train/updates", 0) for line in lines)
    assert updates == 2 + (160 - 32) // 16  # pretraining, then one update a training call
    assert all(np.isfinite(line["train/wm/loss"]) for line in lines if "train/wm/loss" in line)
    gate_lines = [line for line in lines if "gates/open" in line]
    assert bool(gate_lines) == (model == "vsg")  # with the task's gap and the cue-step gate
    assert all({"gates/holding_3", "gates/prob_step1"} <= set(line) for line in gate_lines)
    # units written at the cue and held to the query, where a batch holds a whole episode
    held = [line for line in gate_lines if "gates/written_and_held_3" in line]
    assert bool(held) == (model == "vsg")
    assert all(0 <= line["gates/written_and_held_3"] <= 1
               and 0 < line["gates/null_written_and_held_3"] < 1 for line in held)
    episodes = sorted((tmp_path / "whole" / "episodes").iterdir())
    assert len(episodes) == 160 // 4  # one file per finished episode (4 env steps each)
    assert evaluate.main([str(tmp_path / "whole"), "--episodes", "4"]) == 0  # host evaluator
