"""Both loops log the world model's open-loop errors at every evaluation: ``open_loop.jsonl``
(one line per evaluation) and the ``eval/open_loop/*`` scalars of the eval record; an agent
without a world model (DrQ-v2) writes neither; a resumed run drops the lines after its step.

The trainers are built and evaluated directly (no update is compiled): an evaluation needs no
training, and what is tested is what an evaluation writes.
"""

from __future__ import annotations

import functools
import json

import jax
import numpy as np

from tests.support.fake_envs import FakeImageEnv
from vsgjax.config import make_config
from vsgjax.data import checkpoint
from vsgjax.data.collect import EnvBatch
from vsgjax.envs.mjx import make_mjx_task
from vsgjax.envs.wrappers import DefaultSeed
from vsgjax.episode_keys import VECTOR_KEY
from vsgjax.loop.device_program import DeviceProgram
from vsgjax.loop.device_trainer import DeviceTrainer
from vsgjax.loop.host_trainer import HostTrainer
from vsgjax.loop.parallel import take
from vsgjax.loop.rundir import OPEN_LOOP_FILE, RunWriter

DEVICE_TASK, HOST_TASK = "mjx_cartpole_balance", "dmc_walker_walk"
SCALARS = [f"eval/open_loop/{name}_{k}" for name in ("obs_mse", "reward_mse")
           for k in (5, 15, 35)]


def read_lines(path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def eval_records(logdir) -> list[dict]:
    return [r for r in read_lines(logdir / "metrics.jsonl") if "eval/return" in r]


def check_lines_and_scalars(logdir, steps: list[int]) -> list[dict]:
    """One open_loop.jsonl line per evaluation at ``steps``, 35 finite numbers each, and the
    eval records' scalars equal to their entries 5, 15 and 35."""
    lines = read_lines(logdir / OPEN_LOOP_FILE)
    assert [line["step"] for line in lines] == steps
    assert json.loads((logdir / "scores.jsonl").read_text())["xs"] == [float(s) for s in steps]
    records = eval_records(logdir)
    assert [r["step"] for r in records] == steps
    for line, record in zip(lines, records, strict=True):
        for name in ("obs_mse", "reward_mse"):
            assert len(line[name]) == 35 and all(np.isfinite(line[name]))
            for k in (5, 15, 35):
                assert record[f"eval/open_loop/{name}_{k}"] == line[name][k - 1]
        assert line["obs_mse"][0] > 0  # an untrained model does not predict the episode
    return lines


def evaluate_twice(trainer, agent_steps: int) -> None:
    """Two evaluations, ``agent_steps`` agent steps apart (no videos)."""
    try:
        trainer.counters.next_video = 10**9
        trainer.evaluate()
        trainer.counters.agent_steps += agent_steps
        trainer.evaluate()
    finally:
        trainer.close()


def test_the_device_loop_computes_them_in_its_compiled_evaluation(tmp_path):
    """50 agent steps per episode (51 records): the full 15 + 35 test on both eval episodes,
    from the evaluation's own records (the reset step first)."""
    config = make_config(DEVICE_TASK, "vsg", "debug", ["env.time_limit=100", "env.num_envs=2",
                                                       "train.eval_episodes=2"])
    trainer = DeviceTrainer([config], [tmp_path], progress=False, out=lambda *_: None)
    program, state = trainer.program, take(trainer.state.agent, 0)
    evaluate_twice(trainer, 50)
    lines = check_lines_and_scalars(tmp_path, [0, 100])
    key = jax.random.fold_in(jax.random.PRNGKey(0), 0)  # the seed's evaluation key at step 0
    records = jax.device_get(jax.jit(program.eval_records, static_argnums=2)(state, key, 2))
    assert records[VECTOR_KEY].shape == (2, 51, 5)
    assert records["is_first"][:, 0].all() and not records["is_first"][:, 1:].any()
    assert (records["action"][:, 0] == 0).all() and (records["reward"][:, 0] == 0).all()
    returns = [r["return"] for r in read_lines(tmp_path / "eval_episodes.jsonl")[:2]]
    np.testing.assert_allclose(records["reward"].sum(1), returns, rtol=1e-5)
    expected = jax.device_get(program.agent.open_loop_errors(state, records,
                                                             jax.random.fold_in(key, 1)))
    np.testing.assert_allclose(lines[0]["obs_mse"], expected["obs_mse"], rtol=1e-4)
    np.testing.assert_allclose(lines[0]["reward_mse"], expected["reward_mse"], rtol=1e-4)


def test_the_compiled_evaluation_of_an_agent_without_a_world_model_has_none():
    """DrQ-v2 offers no hook: its evaluation returns the returns alone, so the driver writes no
    line (see the last test). Shapes only: traced, not compiled."""
    config = make_config(DEVICE_TASK, "drqv2", "debug", ["env.time_limit=40"])
    program = DeviceProgram(config, make_mjx_task(DEVICE_TASK, 2, 40))
    assert getattr(program.agent, "open_loop_errors", None) is None
    key = jax.random.PRNGKey(0)
    state = jax.eval_shape(program.agent.init, key)
    shapes = jax.eval_shape(functools.partial(program.evaluate, episodes=3), state, key)
    assert set(shapes) == {"return"} and shapes["return"].shape == (3,)


def fake_envs(env_cfg, seed: int, num_envs: int, *, eval: bool = False) -> EnvBatch:
    """Episodes of 50-52 agent steps (51-53 records) of the fake 64x64 image env."""
    base = seed + 1000 if eval else seed
    return EnvBatch([functools.partial(lambda s: DefaultSeed(FakeImageEnv(length=50), s),
                                       base + i) for i in range(num_envs)], workers=False)


def test_the_host_loop_computes_them_on_the_recorded_eval_episode(tmp_path):
    config = make_config(HOST_TASK, "vsg", "debug")
    trainer = HostTrainer(config, tmp_path, make_envs=fake_envs, progress=False)
    evaluate_twice(trainer, 25)
    check_lines_and_scalars(tmp_path, [0, 50])
    assert not list((tmp_path / "videos").glob("*.mp4"))


def test_a_resumed_run_drops_the_lines_after_its_step_and_short_episodes_log_fewer(tmp_path):
    """Lines are appended per evaluation and truncated to the restored step like the other
    logs; a 14-step test (a short episode) logs the scalars it reaches (step 5); NaN is null."""
    config = make_config(DEVICE_TASK, "vsg", "debug")
    summary = {"return": 1.0, "return_std": 0.0, "wall_s": 1.0, "cpu_s": 1.0}
    errors = {"obs_mse": np.linspace(0.1, 1.0, 14), "reward_mse": np.full(14, np.nan)}
    run = RunWriter(config, tmp_path)
    run.open_logs(0)
    for step in (100, 200):
        run.record_eval(step, [{"return": 1.0}], summary, errors)
    run.record_eval(300, [{"return": 1.0}], summary)  # no errors: no line
    run.close()
    lines = read_lines(tmp_path / OPEN_LOOP_FILE)
    assert [line["step"] for line in lines] == [100, 200]
    np.testing.assert_allclose(lines[0]["obs_mse"], errors["obs_mse"])
    assert lines[0]["reward_mse"] == [None] * 14
    record = eval_records(tmp_path)[0]
    assert record["eval/open_loop/obs_mse_5"] == lines[0]["obs_mse"][4]
    assert record["eval/open_loop/reward_mse_5"] is None
    assert not any(key.endswith(("_15", "_35")) for key in record)
    checkpoint.save(tmp_path / "checkpoints", 150, {"x": np.zeros(1)})  # a run to resume
    run = RunWriter(config, tmp_path)
    run.open_logs(150)
    run.close()
    assert [line["step"] for line in read_lines(tmp_path / OPEN_LOOP_FILE)] == [100]
