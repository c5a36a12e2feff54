"""The gymnax family (vsgjax/envs/gymnax_tasks.py): bsuite's MemoryChain in gymnax's JAX port,
checked against bsuite's own numpy environment, and the family's options and refusals."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from bsuite.environments.memory_chain import MemoryChain

from vsgjax import train
from vsgjax.config import ConfigError, make_config
from vsgjax.envs import TaskError, make_device_task, parse_task
from vsgjax.envs.gymnax_tasks import OBS_KEY, MemoryChainTask

TASK = "gymnax_memory_len"


def gymnax_episode(task: MemoryChainTask, key: jax.Array, actions: list[int]):
    """(context bit, observations [L + 2, 3], rewards [L + 1], ends [L + 1]) of one episode."""
    reset, step = jax.jit(task.reset), jax.jit(task.step)
    state = reset(key)
    observations, rewards, ends = [state.obs[OBS_KEY]], [], []
    for action in actions:
        state = step(state, jax.nn.one_hot(action, 2))
        observations.append(state.obs[OBS_KEY])
        rewards.append(float(state.reward))
        ends.append((bool(state.is_last), bool(state.is_terminal)))
    return int(state.env.context[0]), np.stack(observations), rewards, ends


def bsuite_episode(length: int, context: int, actions: list[int]):
    """The same quantities from bsuite's ``MemoryChain`` with its context bit set to ``context``
    (bsuite draws it from its own RandomState at reset; the reset observation is recomputed)."""
    env = MemoryChain(memory_length=length, num_bits=1, seed=0)
    env.reset()
    env._context = np.array([context])
    observations, rewards, ends = [env._get_observation()], [], []
    for action in actions:
        timestep = env.step(action)
        observations.append(timestep.observation)
        rewards.append(float(timestep.reward))
        ends.append((timestep.last(), timestep.last() and timestep.discount == 0))
    return np.concatenate(observations), rewards, ends


@pytest.mark.parametrize("length", [1, 3, 12])
def test_memory_chain_gives_bsuites_observations_rewards_and_ends(length):
    """Same context and actions: bsuite's rewards and terminations exactly, its observations
    to float32 rounding (gymnax computes the countdown 1 - t / L in float32 on the device:
    -3e-8 where bsuite's is 0), as a flat [3] vector where bsuite's is [1, 3]."""
    task, rng, contexts = MemoryChainTask(length), np.random.default_rng(length), set()
    for episode in range(6):
        actions = [int(a) for a in rng.integers(0, 2, length + 1)]
        context, observations, rewards, ends = gymnax_episode(
            task, jax.random.PRNGKey(episode), actions)
        contexts.add(context)
        expected = bsuite_episode(length, context, actions)
        np.testing.assert_allclose(observations, expected[0], rtol=0, atol=1e-6)
        assert rewards == expected[1] and ends == expected[2]
        assert ends[-1] == (True, True) and not any(any(end) for end in ends[:-1])
        assert rewards[-1] == (1.0 if actions[-1] == context else -1.0)
        assert observations[0, 2] == observations[1, 2] == 2 * context - 1  # seen twice
        assert not observations[2:, 2].any()
    assert contexts == {0, 1}


def test_the_task_is_the_device_interface():
    task = make_device_task(make_config(TASK, "vsg", "debug", ["env.memory_length=7"]).env)
    assert task == MemoryChainTask(7) and hash(task) == hash(MemoryChainTask(7))
    assert (task.episode_steps, task.action_dim, task.discrete, task.action_repeat) == (8, 2,
                                                                                        True, 1)
    assert task.observation_spec() == {OBS_KEY: ((3,), jnp.float32)}
    states = jax.vmap(task.reset)(jax.random.split(jax.random.PRNGKey(0), 4))
    assert task.flat_obs(states.obs).shape == (4, 3) and states.is_first.all()


@pytest.mark.parametrize("task, overrides, message", [
    (TASK, ["env.memory_length=0"], "config key 'env.memory_length' got 0; valid: >= 1"),
    (TASK, ["env.memory_length=12", "train.length=10"],
     "train.length=10 with env.memory_length=12: the context is shown at the first two stored "
     "steps"),
    (TASK, ["env.memory_length=12", "train.length=10"],
     "valid: train.length >= 13, or env.memory_length <= 9"),
    (TASK, ["env.action_repeat=2"], "env.action_repeat=2 for 'gymnax_memory_len'"),
    (TASK, ["env.memory_length=9", "env.time_limit=9"],
     "env.time_limit=9 ends an episode of 'gymnax_memory_len' with env.memory_length=9 before "
     "its reward at step 10; valid: >= 10"),
    (TASK, ["train.loop=host"], "valid: train.loop=device or auto"),
    (TASK, ["env.hide=velocity"], "env.hide='velocity' is an option of the mjx_<domain>_<task> "
                                  "tasks; valid for task 'gymnax_memory_len': env.hide=''"),
    ("mjx_cartpole_swingup", ["env.memory_length=3"],
     "env.memory_length=3 is an option of the gymnax_<env> tasks; valid for task "
     "'mjx_cartpole_swingup': env.memory_length=5"),
    ("bbs_basic", ["env.memory_length=3"], "valid for task 'bbs_basic': env.memory_length=5"),
])
def test_a_bad_option_is_refused_naming_the_value_and_what_is_valid(task, overrides, message):
    with pytest.raises(ConfigError) as error:
        make_config(task, "vsg", "debug", overrides)
    assert message in str(error.value)


def test_a_continuous_only_agent_and_an_unknown_env_are_refused(tmp_path, capsys):
    with pytest.raises(ConfigError, match="acts in a discrete action space"):
        make_config(TASK, "drqv2", "debug")
    with pytest.raises(TaskError, match="unknown gymnax env in 'gymnax_cartpole'; valid: "
                                        "gymnax_memory_len"):
        parse_task("gymnax_cartpole")
    logdir = tmp_path / "run"
    assert train.main(["--task", "gymnax_memory_len", "--size", "debug", "--logdir",
                       str(logdir), "env.memory_length=20", "--no-progress"]) == 2
    assert "train.length=10 with env.memory_length=20" in capsys.readouterr().err
    assert not logdir.exists()
