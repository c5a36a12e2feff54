"""The host loop on MJX tasks (vsgjax/envs/mjx/vector_env.py through vsgjax/data/collect.py's
EnvBatch).

A debug VSG on ``mjx_cartpole_balance`` with a 40-step time limit (20 agent steps per episode)
and 2 envs, the setting of tests/loop/test_device_loop.py.
"""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

from vsgjax import train
from vsgjax.analysis.evaluation import evaluate_logdir
from vsgjax.analysis.load import load
from vsgjax.config import ConfigError, make_config
from vsgjax.data import checkpoint
from vsgjax.data.collect import EnvBatch, make_env_batch
from vsgjax.data.replay.store import read_episode
from vsgjax.envs import EVAL_SEED_OFFSET, EnvSpec, TaskError, make_env
from vsgjax.envs.mjx import make_mjx_task
from vsgjax.envs.mjx.vector_env import MjxVectorEnv, seed_keys
from vsgjax.episode_keys import VECTOR_KEY
from vsgjax.loop.device_program import DeviceProgram
from vsgjax.loop.host_trainer import HostTrainer
from vsgjax.observations import ObsSpec

TASK = "mjx_cartpole_balance"
SHORT = ["env.time_limit=40", "env.num_envs=2", "train.length=8", "train.batch=3",
         "train.train_every=5", "train.prefill=80", "train.pretrain=2"]
RECORD_KEYS = (VECTOR_KEY, "action", "reward", "is_first", "is_terminal")


def config(*overrides: str):
    return make_config(TASK, "vsg", "debug", [*SHORT, *overrides])


@pytest.fixture(scope="module")
def loop() -> DeviceProgram:
    env = config().env
    return DeviceProgram(config(), make_mjx_task(TASK, env.action_repeat, env.time_limit))


def next_reset_keys(keys: jax.Array) -> jax.Array:
    """The keys ``MjxTask.reset(key)`` leaves in the state for the next episode's reset."""
    return jax.vmap(lambda key: jax.random.split(key)[0])(keys)


def test_the_host_loop_makes_the_device_loops_episodes_bitwise(loop):
    """One prefill call of the device loop; the host adapter, started from the same reset keys
    (the loop's ``split(reset_key, N)``) and given the recorded actions through EnvBatch,
    finishes the same episodes, bit for bit: both run the same float32 ``task.step`` and
    ``task.reset`` (jitted and vmapped) on the same inputs, on the CPU, which XLA evaluates
    identically whether the step sits in the loop's scan or stands alone."""
    state = loop.init(jax.random.PRNGKey(0))
    _, _, records = jax.jit(lambda s: loop.episode(s, False))(state)
    records = jax.device_get(records)
    reset_key = jax.random.split(state.key, 3 + loop.updates_per_episode)[1]
    keys = jax.random.split(reset_key, 2)
    envs = EnvBatch(MjxVectorEnv(loop.task, keys))
    assert envs.spec == EnvSpec(ObsSpec.from_dict({VECTOR_KEY: (5,)}), 1, False)
    envs.reset()
    for t in range(1, loop.episode_steps + 1):
        obs = envs.step(records["action"][:, t])
    assert obs["is_last"].all() and not obs["is_terminal"].any()
    assert [(index, info["length"]) for _, index, info in envs.finished] == [(0, 20), (1, 20)]
    for episode, index, info in envs.finished:
        assert sorted(episode) == sorted(RECORD_KEYS)
        for key in RECORD_KEYS:
            np.testing.assert_array_equal(episode[key], records[key][index], err_msg=key)
        assert info["return"] == pytest.approx(float(records["reward"][index].sum()))

    # NEXT_STEP autoreset: the action is ignored, the next episode starts from the state's key
    obs = envs.step(np.full((2, 1), 0.7, np.float32))
    assert obs["is_first"].all() and (obs["reward"] == 0).all() and not obs["is_last"].any()
    fresh = jax.jit(jax.vmap(loop.task.reset))(next_reset_keys(keys))
    np.testing.assert_array_equal(obs[VECTOR_KEY], loop.task.flat_obs(fresh.obs))
    envs.close()


def test_env_batches_are_seeded_seed_plus_i_and_eval_envs_on_the_disjoint_range(loop):
    task, env_cfg = loop.task, config().env
    reset = jax.jit(jax.vmap(task.reset))
    for eval, offset in ((False, 0), (True, EVAL_SEED_OFFSET)):
        envs = make_env_batch(env_cfg, 3, 2, eval=eval)
        first = envs.reset()[VECTOR_KEY]
        expected = task.flat_obs(reset(seed_keys([3 + offset, 4 + offset])).obs)
        np.testing.assert_array_equal(first, expected)
        np.testing.assert_array_equal(make_env_batch(env_cfg, 3, 2, eval=eval).reset()[
            VECTOR_KEY], first)  # same seed, same episodes
        # reset() again starts the envs' next episodes (their key streams go on)
        again = envs.reset()[VECTOR_KEY]
        keys = next_reset_keys(seed_keys([3 + offset, 4 + offset]))
        np.testing.assert_array_equal(again, task.flat_obs(reset(keys).obs))
        assert not np.array_equal(again, first)


# --- the whole host loop -----------------------------------------------------------------------


def read_jsonl(path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


@pytest.mark.slow  # ~1.5 minutes on 2 cores: it compiles the agent's update and the MJX step
def test_host_loop_trains_an_mjx_task_writes_the_log_directory_and_resumes(tmp_path, capsys):
    overrides = ["train.loop=host", "train.eval_every=120", "train.log_every=80",
                 "train.ckpt_every=5"]
    trainer = train.make_trainer([config(*overrides, "train.steps=240")], [tmp_path],
                                 progress=False)
    assert isinstance(trainer, HostTrainer)
    assert trainer.describe() == "starting a new run"
    try:
        assert trainer.run() == 0
    finally:
        trainer.close()
    out = capsys.readouterr().out
    assert "done: 240 env steps" in out
    assert out.count("no videos: the observations of mjx_cartpole_balance have no image") == 1
    for name in ("config.json", "metrics.jsonl", "scores.jsonl", "eval_episodes.jsonl"):
        assert (tmp_path / name).exists(), name
    assert not list((tmp_path / "videos").iterdir())
    episodes = sorted((tmp_path / "episodes").glob("*.mcap"))
    # 120 agent steps: per env, 20 steps, a reset step (NEXT_STEP), 20 steps, a reset step, ...
    assert len(episodes) == 4
    episode = read_episode(episodes[0])
    assert episode[VECTOR_KEY].shape == (21, 5) and "image" not in episode
    scores = json.loads((tmp_path / "scores.jsonl").read_text())
    assert scores["xs"] == [80.0, 200.0, 240.0]  # prefill end, the grid, the final score
    updates = [r["train/updates"] for r in read_jsonl(tmp_path / "metrics.jsonl")
               if "train/updates" in r]
    assert updates and all("train/wm/vector_mse" in r for r in read_jsonl(
        tmp_path / "metrics.jsonl") if "train/wm/loss" in r)
    assert checkpoint.list_checkpoints(tmp_path / "checkpoints")

    resumed = train.make_trainer([config(*overrides, "train.steps=320")], [tmp_path],
                                 progress=False)
    try:
        assert resumed.describe().startswith("resuming from ckpt-000000000240.ckpt: env step 240")
        assert resumed.run() == 0
    finally:
        resumed.close()
    assert "done: 320 env steps" in capsys.readouterr().out
    assert json.loads((tmp_path / "scores.jsonl").read_text())["xs"][-1] == 320.0

    run = load(tmp_path)  # the notebook API reads the vector spec from the episodes
    assert run.spec.obs == ObsSpec.from_dict({VECTOR_KEY: (5,)}) and run.step == 320
    posts = run.observe(run.episode(-1))
    assert jax.tree.leaves(posts)[0].shape[0] == 21
    infos, step = evaluate_logdir(tmp_path, episodes=1)
    assert step == 320 and infos[0]["length"] == 20


# --- bad input ---------------------------------------------------------------------------------


def test_loops_resolve_and_bad_input_says_why():
    assert train.resolve_loop(config("train.loop=host")) == "host"
    assert train.resolve_loop(config()) == "device"
    with pytest.raises(ConfigError, match=r"steps inside JAX .* 'bbs_basic' is a host "
                                          r"environment \(gymnasium, stepped in Python\)"):
        train.resolve_loop(make_config("bbs_basic", "vsg", "debug", ["train.loop=device"]))
    with pytest.raises(TaskError, match="the host loop"):
        make_env(config().env, 0)
    with pytest.raises(ValueError, match="grayscale=True"):
        make_env_batch(config("env.grayscale=True").env, 0, 2)


def test_the_vector_env_rejects_bad_keys_actions_and_workers(loop):
    with pytest.raises(ValueError, match=r"\[N, 2\] PRNG keys .* got shape \(2,\)"):
        MjxVectorEnv(loop.task, jax.random.PRNGKey(0))
    envs = MjxVectorEnv(loop.task, seed_keys([0, 1]))
    with pytest.raises(RuntimeError, match="reset"):
        envs.step(np.zeros((2, 1)))
    with pytest.raises(ValueError, match="workers=True"):
        EnvBatch(envs, workers=True)
    envs.reset()
    with pytest.raises(ValueError, match=r"shape \(2, 1\) .* got \(3, 1\)"):
        envs.step(np.zeros((3, 1)))
    with pytest.raises(ValueError, match="one seed per env"):
        envs.reset(seed=[1, 2, 3])


def test_an_image_encoder_on_vector_observations_is_a_config_error(tmp_path):
    with pytest.raises(ConfigError, match="wm.encoder=cnn cannot encode the vector keys"):
        train.make_trainer([config("train.loop=host", "wm.encoder=cnn")], [tmp_path],
                           progress=False)
