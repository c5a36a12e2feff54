"""The fully jitted loop of MJX tasks (vsgjax/loop/device_program.py, device_trainer.py).

A debug VSG on ``mjx_cartpole_balance`` with a 40-step time limit (20 agent steps per episode)
and 2 envs, so that one compiled call is cheap.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tests.support.overrides import replaced
from vsgjax import train
from vsgjax.config import ConfigError, make_config
from vsgjax.data import checkpoint
from vsgjax.data.replay.device import DeviceReplay, store_episodes
from vsgjax.envs import TaskError
from vsgjax.envs.mjx import make_mjx_task
from vsgjax.episode_keys import VECTOR_KEY
from vsgjax.loop.device_program import DeviceProgram

ROOT = Path(__file__).resolve().parents[2]
TASK = "mjx_cartpole_balance"
SHORT = ["env.time_limit=40", "env.num_envs=2", "train.length=8", "train.batch=3",
         "train.train_every=5", "train.prefill=80", "train.pretrain=2"]


def make_loop(*overrides: str) -> DeviceProgram:
    config = make_config(TASK, "vsg", "debug", replaced(SHORT, *overrides))
    env = config.env
    return DeviceProgram(config, make_mjx_task(TASK, env.action_repeat, env.time_limit))


@pytest.fixture(scope="module")
def loop() -> DeviceProgram:
    return make_loop()


@pytest.fixture(scope="module")
def prefill_episode(loop):
    """(state before, state after, records) of one jitted prefill call."""
    state = loop.init(jax.random.PRNGKey(0))
    after, metrics, records = jax.jit(lambda s: loop.episode(s, False))(state)
    assert metrics == {}
    return state, after, jax.device_get(records)


def test_sizes_follow_the_config(loop):
    assert loop.episode_steps == 20 and loop.updates_per_episode == 4
    assert loop.obs_dim == 5 and loop.task.action_dim == 1  # cartpole: position 3, velocity 2
    assert loop.replay_episodes == 10_000 // (2 * 21)


def test_an_episode_call_records_the_host_format_and_stores_it(prefill_episode, loop):
    _, after, records = prefill_episode
    assert records[VECTOR_KEY].shape == (2, 21, 5) and records["action"].shape == (2, 21, 1)
    assert records["is_first"][:, 0].all() and not records["is_first"][:, 1:].any()
    assert not records["is_terminal"].any()
    assert (records["action"][:, 0] == 0).all() and (records["reward"][:, 0] == 0).all()
    assert (np.abs(records["action"][:, 1:]) <= 1).all() and records["action"][:, 1:].std() > 0.3
    assert int(after.replay.stored) == 1
    np.testing.assert_array_equal(after.replay.data[VECTOR_KEY][0], records[VECTOR_KEY])


def test_the_jitted_call_makes_the_transitions_of_a_python_loop_over_the_same_env(
        prefill_episode, loop):
    """Same keys, same random prefill policy: a Python loop of ``task.step`` agrees."""
    state, _, records = prefill_episode
    keys = jax.random.split(state.key, 3 + loop.updates_per_episode)
    envs, carry, _ = loop._reset(2, keys[1])
    policy = jax.jit(loop._policy("train"))
    step = jax.jit(jax.vmap(loop.task.step))
    params, explore = state.agent.params, jnp.asarray(True)
    step_keys = [k for block in keys[3:] for k in jax.random.split(jax.random.split(block)[0], 5)]
    vectors = [loop.task.flat_obs(envs.obs)]
    for key in step_keys:
        obs = {VECTOR_KEY: loop.task.flat_obs(envs.obs), "is_first": envs.is_first}
        carry, action = policy((params, explore), carry, obs, key)
        envs = step(envs, action)
        vectors.append(loop.task.flat_obs(envs.obs))
    np.testing.assert_allclose(np.stack(vectors, 1), records[VECTOR_KEY], rtol=1e-5, atol=1e-5)


def synthetic_replay(loop: DeviceProgram, stored: int) -> DeviceReplay:
    """A replay whose step values encode (episode batch, env, time) and mark episode starts."""
    m, n, t = loop.replay_episodes, 2, loop.episode_steps + 1
    index = np.arange(m * n * t, dtype=np.float32).reshape(m, n, t)
    data = {VECTOR_KEY: jnp.asarray(np.repeat(index[..., None], 5, -1)),
            "action": jnp.zeros((m, n, t, 1)), "reward": jnp.asarray(index),
            "is_first": jnp.asarray(np.broadcast_to(np.arange(t) == 0, (m, n, t))),
            "is_terminal": jnp.zeros((m, n, t), bool)}
    return DeviceReplay(data, jnp.asarray(stored, jnp.int32))


def test_sampled_sequences_never_cross_an_episode_and_only_read_stored_ones(loop):
    t = loop.episode_steps + 1
    replay = synthetic_replay(loop, stored=3)
    sample = jax.jit(loop.sample)
    for seed in range(20):
        batch = jax.device_get(sample(replay, jax.random.PRNGKey(seed)))
        value = batch["reward"]
        assert value.shape == (3, 8)
        np.testing.assert_array_equal(np.diff(value, axis=1), 1)  # consecutive steps
        episode = value[:, 0] // t
        assert (episode == value[:, -1] // t).all()  # one episode batch and env per sequence
        assert (episode // 2 < 3).all()  # only the 3 stored batches
        assert not batch["is_first"][:, 1:].any()


def test_the_ring_overwrites_the_oldest_episode_batch(loop):
    replay = synthetic_replay(loop, stored=0)
    records = {k: jnp.full(v.shape[1:], 7, v.dtype) for k, v in replay.data.items()}
    for _ in range(loop.replay_episodes + 1):
        replay = store_episodes(replay, records)
    assert int(replay.stored) == loop.replay_episodes + 1
    assert float(replay.data["reward"][0].min()) == 7  # slot 0 written twice
    assert float(replay.data["reward"][1].max()) == 7


def test_sequences_longer_than_an_episode_are_an_error():
    with pytest.raises(ValueError, match=r"train.length=30 .* valid: <= 21"):
        make_loop("train.length=30").check()


def test_loop_and_task_mismatches_are_errors_that_say_why(capsys, tmp_path):
    with pytest.raises(ConfigError, match="steps inside JAX .* 'bbs_basic' is a host environment"):
        train.resolve_loop(make_config("bbs_basic", "vsg", "debug", ["train.loop=device"]))
    assert train.resolve_loop(make_config(TASK, "vsg", "debug", ["train.loop=host"])) == "host"
    assert train.resolve_loop(make_config(TASK, "vsg", "debug")) == "device"
    assert train.main(["--task", "mjx_cartpole_fly", "--logdir", str(tmp_path)]) == 2
    assert "valid: mjx_cartpole_balance, mjx_cartpole_swingup" in capsys.readouterr().err
    with pytest.raises(TaskError, match="trains with the device loop"):
        from vsgjax.envs import make_env
        make_env(make_config(TASK, "vsg", "debug").env, 0)


# --- end to end ----------------------------------------------------------------------------


def command(logdir: Path, *overrides: str) -> list[str]:
    return [sys.executable, "-m", "vsgjax.train", "--task", TASK, "--size", "debug",
            "--logdir", str(logdir), "--no-progress", *replaced(SHORT, *overrides)]


@pytest.mark.slow
def test_a_seeds_non_finite_update_stops_only_that_seed(tmp_path, capsys):
    """Seed 1's updates of the first training call are NaN: seed 1 stops, seed 0 finishes."""
    from vsgjax.loop.device_trainer import DeviceTrainer

    configs = [make_config(TASK, "vsg", "debug",
                           replaced(SHORT, f"train.seed={seed}", "train.steps=240",
                                    "train.ckpt_every=4", "train.pretrain=0"))
               for seed in (0, 1)]
    trainer = DeviceTrainer(configs, [tmp_path / "a", tmp_path / "b"], progress=False,
                            out=lambda *_: None)
    real_episode = trainer._episode[True]

    def poisoned(state):
        state, metrics, records = real_episode(state)
        return state, dict(metrics, **{"wm/loss": metrics["wm/loss"].at[1].set(jnp.nan)}), records

    trainer._episode[True] = poisoned
    try:
        assert trainer.run() == 1
    finally:
        trainer.close()
    err = capsys.readouterr().err
    assert "seed 1: training stopped: non-finite metrics at update 1" in err
    assert "wm/loss=nan" in err and "the other seeds go on" in err
    assert trainer.stopped == [1] and [run.seed for run in trainer.runs] == [0]
    assert not checkpoint.list_checkpoints(tmp_path / "b" / "checkpoints")  # none after prefill
    scores = json.loads((tmp_path / "a" / "scores.jsonl").read_text())
    assert scores["xs"][-1] == 240  # 80 env steps per call
    updates = [json.loads(line).get("train/updates")
               for line in (tmp_path / "a" / "metrics.jsonl").read_text().splitlines()]
    assert max(u for u in updates if u is not None) > 6  # seed 0 went on training


SPREAD = textwrap.dedent("""
    import json, sys
    from pathlib import Path
    from vsgjax import train
    root, flags = Path(sys.argv[1]), sys.argv[2:]
    for devices in (1, 2):
        args = ["--task", "mjx_cartpole_balance", "--size", "debug", "--seeds", "0,1",
                "--logdir", str(root / f"d{devices}-s{{seed}}"), "--no-progress", *flags,
                "train.steps=160", f"train.devices={devices}"]
        assert train.main(args) == 0
    rc = train.main(["--task", "mjx_cartpole_balance", "--size", "debug", "--seeds", "0,1,2",
                     "--logdir", str(root / "three-s{seed}"), *flags, "train.devices=2"])
    print("three seeds on two devices: rc", rc)
""")


@pytest.mark.slow
def test_seeds_spread_over_two_forced_host_devices_train_as_on_one(tmp_path):
    """Two seeds on two host devices (one program, each seed's loop on its own device) give
    the metrics and scores of the same two seeds on one device, to float rounding."""
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu")
    flags = replaced(SHORT, "train.pretrain=0")
    result = subprocess.run([sys.executable, "-c", SPREAD, str(tmp_path), *flags], cwd=ROOT,
                            env=env, capture_output=True, text=True, timeout=900)
    assert result.returncode == 0, result.stderr[-3000:]
    assert "2 seeds in one program, spread over 2 devices" in result.stdout
    assert "three seeds on two devices: rc 2" in result.stdout
    assert ("error: train.devices=2 does not divide the 3 seeds: the device loop spreads "
            "whole seeds over the devices; valid: a divisor of 3") in result.stderr
    assert not any(tmp_path.glob("three-*"))  # nothing written
    for seed in (0, 1):
        one, two = (tmp_path / f"d{devices}-s{seed}" for devices in (1, 2))
        scores = [json.loads((run / "scores.jsonl").read_text()) for run in (one, two)]
        assert scores[0]["xs"] == scores[1]["xs"] == [160.0]
        np.testing.assert_allclose(scores[0]["ys"], scores[1]["ys"], rtol=1e-4)
        lines = [[json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
                 for run in (one, two)]
        assert len(lines[0]) == len(lines[1])
        for a, b in zip(*lines, strict=True):
            for key, value in a.items():
                if key.startswith(("train/", "gates/")) and not key.endswith("_s"):
                    np.testing.assert_allclose(b[key], value, rtol=1e-4, atol=1e-6, err_msg=key)
