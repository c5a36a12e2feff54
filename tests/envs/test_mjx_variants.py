"""Partially observed and noisy variants of the MJX tasks (vsgjax/envs/mjx/variants.py), their
config keys (env.flicker, env.hide, env.show_keys, env.show_steps, env.noise_dims,
env.noise_scale) and the memoryless control (ac.memoryless, ac.memoryless_starts).

Every rollout is pendulum swingup (the quickest task to compile): ENVS envs for STEPS agent
steps, action repeat 1, one jitted program per task (cached), each compared with the plain
task rolled out from the same reset keys under the same actions.
"""

from __future__ import annotations

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vsgjax import train
from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.config import ConfigError, make_config
from vsgjax.envs import make_device_task
from vsgjax.envs.mjx import MjxTask, make_mjx_task
from vsgjax.envs.mjx.variants import NOISE_KEY, VariantTask
from vsgjax.episode_keys import VECTOR_KEY
from vsgjax.loop.device_program import DeviceProgram

TASK = "mjx_pendulum_swingup"  # observation: orientation (2), velocity (1)
ENVS, STEPS = 64, 24
PLAIN = make_mjx_task(TASK, action_repeat=1, time_limit=STEPS)
P, K, SCALE, SHOWN = 0.3, 4, 0.5, 3
# one compiled rollout per task: hiding and showing once share one (pendulum has two keys)
MASKED = VariantTask(PLAIN, hide=("velocity",), show_keys=("orientation",), show_steps=SHOWN)
NOISY = VariantTask(PLAIN, flicker=P, noise_dims=K, noise_scale=SCALE)


def keys(seed: int = 0) -> jax.Array:
    return jax.random.split(jax.random.PRNGKey(seed), ENVS)


def actions(seed: int = 0) -> jax.Array:
    return jax.random.uniform(jax.random.PRNGKey(1000 + seed), (STEPS, ENVS, 1),
                              minval=-1.0, maxval=1.0)


@functools.partial(jax.jit, static_argnums=0)
def _rollout(task, reset_keys, step_actions) -> dict:
    """``[STEPS + 1, ENVS, ...]`` of what the agent sees (t = 0: reset) and the variant state."""

    def seen(state):
        out = {"obs": state.obs, "flat": task.flat_obs(state.obs), "reward": state.reward}
        if isinstance(task, VariantTask):
            out.update(plain=state.plain.obs, flickered=state.flickered, noise=state.noise,
                       t=state.t)
        return out

    first = jax.vmap(task.reset)(reset_keys)

    def step(state, action):
        state = jax.vmap(task.step)(state, action)
        return state, seen(state)

    _, rest = jax.lax.scan(step, first, step_actions)
    return jax.tree.map(lambda a, b: jnp.concatenate([a[None], b]), seen(first), rest)


@functools.cache
def rollout(task, seed: int = 0, action_seed: int = 0) -> dict:
    return jax.device_get(_rollout(task, keys(seed), actions(action_seed)))


# --- each option's semantics ------------------------------------------------------------------


def test_a_hidden_key_is_zero_at_every_step_and_the_task_is_the_plain_one():
    plain, masked = rollout(PLAIN), rollout(MASKED)
    assert np.abs(plain["obs"]["velocity"]).max() > 0.1  # there was something to hide
    assert (masked["obs"]["velocity"] == 0).all()
    for key in PLAIN.obs_keys:  # the wrapped task's own state is the plain task's
        np.testing.assert_array_equal(masked["plain"][key], plain["obs"][key])
    np.testing.assert_array_equal(masked["reward"], plain["reward"])
    assert MASKED.obs_keys == PLAIN.obs_keys and masked["flat"].shape == plain["flat"].shape


def test_a_shown_once_key_is_the_plain_tasks_for_the_first_k_steps_then_zero():
    plain, masked = rollout(PLAIN), rollout(MASKED)
    orientation, want = masked["obs"]["orientation"], plain["obs"]["orientation"]
    np.testing.assert_array_equal(orientation[:SHOWN], want[:SHOWN])  # t = 0 (reset) .. k - 1
    assert (orientation[SHOWN:] == 0).all() and (np.abs(want[SHOWN:]) > 0).any()
    np.testing.assert_array_equal(masked["t"][:, 0], np.arange(STEPS + 1))
    np.testing.assert_array_equal(masked["flat"][:SHOWN, :, :2], want[:SHOWN])  # flat_obs order


def test_flicker_blanks_the_whole_observation_at_rate_p_and_leaves_the_rest_plain():
    plain, noisy = rollout(PLAIN), rollout(NOISY)
    flickered = noisy["flickered"]  # [STEPS + 1, ENVS], the reset observation included
    count = flickered.size
    assert abs(flickered.mean() - P) < 4 * np.sqrt(P * (1 - P) / count)
    assert flickered[0].any() and not flickered[0].all()  # the reset observation flickers too
    assert (noisy["flat"][flickered] == 0).all()  # the whole observation, noise dims included
    seen = ~flickered
    for key in PLAIN.obs_keys:
        np.testing.assert_array_equal(noisy["obs"][key][seen], plain["obs"][key][seen])
    np.testing.assert_array_equal(noisy["obs"][NOISE_KEY][seen], noisy["noise"][seen])
    assert (np.abs(noisy["flat"][seen]).max(-1) > 0).all()
    np.testing.assert_array_equal(noisy["reward"], plain["reward"])


def test_noise_dims_are_a_random_walk_from_zero_with_the_stated_std_whatever_the_actions():
    noisy, other = rollout(NOISY), rollout(NOISY, action_seed=1)
    assert NOISY.obs_keys == (*PLAIN.obs_keys, NOISE_KEY)
    assert NOISY.observation_spec()[NOISE_KEY] == ((K,), jnp.float32)
    assert noisy["flat"].shape == (STEPS + 1, ENVS, 3 + K)
    # other actions move the pendulum elsewhere, and not the noise (nor the flicker)
    assert np.abs(noisy["obs"]["orientation"] - other["obs"]["orientation"]).max() > 1e-3
    np.testing.assert_array_equal(noisy["obs"][NOISE_KEY], other["obs"][NOISE_KEY])
    np.testing.assert_array_equal(noisy["flickered"], other["flickered"])
    walk = noisy["noise"]  # [STEPS + 1, ENVS, K], before flicker
    assert (walk[0] == 0).all()
    increments = np.diff(walk, axis=0).ravel()
    se = SCALE / np.sqrt(2 * increments.size)  # of the sample std of a normal
    assert abs(increments.std() - SCALE) < 4 * se
    assert abs(increments.mean()) < 4 * SCALE / np.sqrt(increments.size)
    lag1 = np.corrcoef(np.diff(walk, axis=0)[1:].ravel(), np.diff(walk, axis=0)[:-1].ravel())
    assert abs(lag1[0, 1]) < 4 / np.sqrt(increments.size)  # independent increments


def test_the_same_reset_keys_give_the_same_episode_and_other_keys_another():
    first = rollout(NOISY)
    again = jax.device_get(_rollout(NOISY, keys(0), actions(0)))
    for name in ("flat", "flickered", "noise", "reward"):
        np.testing.assert_array_equal(first[name], again[name])
    other = rollout(NOISY, seed=1)
    assert (first["flickered"] != other["flickered"]).any()
    assert (first["noise"] != other["noise"]).any()
    assert (first["plain"]["orientation"] != other["plain"]["orientation"]).any()


def test_the_plain_task_is_built_when_no_option_is_set():
    config = make_config(TASK, "vsg", "debug")
    task = make_device_task(config.env)
    assert type(task) is MjxTask and task == make_mjx_task(TASK, config.env.action_repeat,
                                                           config.env.time_limit)
    scale_only = make_config(TASK, "vsg", "debug", ["env.noise_scale=0.7"])
    assert type(make_device_task(scale_only.env)) is MjxTask  # no noise dims to scale
    built = make_device_task(make_config(TASK, "vsg", "debug", [
        "env.flicker=0.2", "env.hide=velocity", "env.noise_dims=2", "env.noise_scale=0.3"]).env)
    assert built == VariantTask(task, flicker=0.2, hide=("velocity",), noise_dims=2,
                                noise_scale=0.3)
    shown = make_device_task(make_config("mjx_reacher_easy", "vsg", "debug", [
        "env.show_keys= to_target", "env.show_steps=1"]).env)
    assert shown.show_keys == ("to_target",) and shown.show_steps == 1
    hash(built), hash(shown)  # jit-static


# --- the device loop -----------------------------------------------------------------------------


def test_the_device_loop_runs_a_vsg_config_with_every_variant():
    config = make_config(TASK, "vsg", "debug", [
        "env.time_limit=20", "env.num_envs=2", "train.length=8", "train.batch=3",
        "train.train_every=5", "env.flicker=0.25", "env.hide=velocity",
        "env.show_keys=orientation", "env.show_steps=2", "env.noise_dims=2"])
    program = DeviceProgram(config, make_device_task(config.env))
    assert program.obs_dim == 2 + 1 + 2 and program.episode_steps == 10
    state = program.init(jax.random.PRNGKey(0))
    _, _, records = jax.device_get(jax.jit(lambda s: program.episode(s, False))(state))
    obs = records[VECTOR_KEY]  # [N, E + 1, orientation 2 | velocity 1 | noise 2]
    assert obs.shape == (2, 11, 5) and np.isfinite(obs).all()
    assert (obs[:, :, 2] == 0).all()  # hidden
    assert (obs[:, 2:, :2] == 0).all()  # shown at t = 0, 1 only
    blank = (obs == 0).all(-1)
    assert blank.any() and not blank.all()  # flicker
    assert (np.abs(obs[:, 1:, 3:]).max(-1)[~blank[:, 1:]] > 0).all()  # the noise walk moves


def test_the_host_loops_vector_env_sees_the_variant_observation():
    from vsgjax.envs.mjx.vector_env import MjxVectorEnv

    noisy = rollout(NOISY)
    env = MjxVectorEnv(NOISY, keys(0))
    assert env.single_observation_space[VECTOR_KEY].shape == (3 + K,)
    first, _ = env.reset()
    np.testing.assert_array_equal(first[VECTOR_KEY], noisy["flat"][0])  # step: the same flat_obs


# --- bad input -----------------------------------------------------------------------------------


@pytest.mark.parametrize("overrides, message", [
    (["env.flicker=1"], "config key 'env.flicker' got 1.0; valid: [0, 1)"),
    (["env.flicker=-0.1"], "config key 'env.flicker' got -0.1; valid: [0, 1)"),
    (["env.noise_dims=-1"], "config key 'env.noise_dims' got -1; valid: >= 0"),
    (["env.noise_scale=-1"], "config key 'env.noise_scale' got -1.0; valid: >= 0"),
    (["env.show_keys=velocity"], "env.show_steps=0 with env.show_keys='velocity'; valid: >= 1"),
    (["env.show_steps=3"], "env.show_steps=3 without env.show_keys; valid: env.show_steps=0"),
    (["ac.memoryless_starts=true"], "ac.memoryless_starts=true without ac.memoryless; valid: "),
])
def test_a_bad_option_is_refused_naming_the_value_and_what_is_valid(overrides, message):
    with pytest.raises(ConfigError) as error:
        make_config(TASK, "vsg", "debug", overrides)
    assert message in str(error.value)


@pytest.mark.parametrize("override, value", [
    ("env.flicker=0.5", "0.5"), ("env.hide=velocity", "'velocity'"),
    ("env.noise_dims=3", "3"), ("env.noise_scale=0.2", "0.2")])
def test_a_variant_option_on_a_host_task_is_refused_naming_task_and_option(override, value):
    key = override.partition("=")[0]
    with pytest.raises(ConfigError) as error:
        make_config("bbs_basic", "vsg", "debug", [override])
    text = str(error.value)
    assert f"{key}={value}" in text and "'bbs_basic'" in text and "valid" in text
    assert "mjx_<domain>_<task>" in text


def test_a_key_the_task_does_not_observe_is_refused_where_the_task_is_built():
    config = make_config("mjx_cartpole_swingup", "vsg", "debug", ["env.hide=velocity,foo"])
    with pytest.raises(ConfigError) as error:
        make_device_task(config.env)
    text = str(error.value)
    assert "'foo'" in text and "valid: comma-separated keys of position, velocity" in text
    config = make_config("mjx_cartpole_swingup", "vsg", "debug",
                         ["env.show_keys=to_target", "env.show_steps=2"])
    with pytest.raises(ConfigError, match="no observation key 'to_target'; valid: comma"):
        make_device_task(config.env)
    with pytest.raises(ConfigError, match="'velocity' is in env.hide and env.show_keys"):
        VariantTask(PLAIN, hide=("velocity",), show_keys=("velocity",), show_steps=1)
    with pytest.raises(ConfigError, match=r"env.flicker=1.0; valid: a probability in \[0, 1\)"):
        VariantTask(PLAIN, flicker=1.0)  # the task checks its options without check_config


def test_the_command_line_refuses_an_unknown_key_before_writing_anything(tmp_path, capsys):
    logdir = tmp_path / "run"
    code = train.main(["--task", "mjx_cartpole_swingup", "--size", "debug", "env.hide=foo",
                       "--logdir", str(logdir), "--no-progress"])
    assert code == 2 and not logdir.exists()
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 1 and errors[0].startswith("error: env.hide='foo'")
    assert "position, velocity" in errors[0]


# --- the memoryless control ---------------------------------------------------------------------


def test_a_memoryless_agent_acts_from_the_observation_alone():
    config = make_config(TASK, "vsg", "debug")
    plain = DreamerAgent(config, {VECTOR_KEY: (3,)}, 1, False)
    memoryless = DreamerAgent(dataclasses.replace(
        config, ac=dataclasses.replace(config.ac, memoryless=True)), {VECTOR_KEY: (3,)}, 1, False)
    params = plain.init(jax.random.PRNGKey(0))
    rng = np.random.default_rng(0)
    vector = rng.normal(size=(2, 3)).astype(np.float32)
    obs = {VECTOR_KEY: vector, "is_first": np.zeros(2, bool)}
    zero = plain.initial_carry(2)
    carries = [jax.tree.map(lambda x, i=i: x + rng.normal(size=x.shape).astype(x.dtype) * (i + 1),
                            zero) for i in range(2)]
    key = jax.random.PRNGKey(5)

    def step(agent, carry, observation):
        return jax.device_get(agent.policy_step(params.params, carry, observation, key,
                                                mode="eval"))

    fresh = step(plain, zero, {**obs, "is_first": np.ones(2, bool)})
    leaves = jax.tree.leaves
    for carry in carries:  # whatever was carried, the posterior of a first step
        for got, want in zip(leaves(step(memoryless, carry, obs)), leaves(fresh), strict=True):
            np.testing.assert_array_equal(got, want)
    carried = step(plain, carries[0], obs)  # without the flag the carry matters
    assert any((a != b).any() for a, b in zip(leaves(carried[0][0]), leaves(fresh[0][0]),
                                              strict=True))


def test_memoryless_starts_imagine_from_the_states_the_control_acts_from():
    """The imagination starts are the acting posteriors of each batch step alone; the world
    model's update is the plain one and the actor's is not."""
    config = make_config(TASK, "dreamerv2", "debug", ["ac.memoryless=true"])
    acting = DreamerAgent(config, {VECTOR_KEY: (3,)}, 1, False)
    starting = DreamerAgent(dataclasses.replace(
        config, ac=dataclasses.replace(config.ac, memoryless_starts=True)), {VECTOR_KEY: (3,)},
        1, False)
    state = acting.init(jax.random.PRNGKey(0))
    rng = np.random.default_rng(1)
    length = 6
    batch = {VECTOR_KEY: rng.normal(size=(2, length, 3)).astype(np.float32),
             "action": rng.uniform(-1, 1, (2, length, 1)).astype(np.float32),
             "reward": rng.normal(size=(2, length)).astype(np.float32),
             "is_first": np.eye(1, length, dtype=bool).repeat(2, 0),
             "is_terminal": np.zeros((2, length), bool)}
    wm = state.params["wm"]
    starts = jax.device_get(starting._posteriors_alone(wm, batch, jax.random.PRNGKey(2)))
    for t in (0, 3):
        obs = {VECTOR_KEY: batch[VECTOR_KEY][:, t], "is_first": np.zeros(2, bool)}
        (posts, _), _ = acting.policy_step(state.params, acting.initial_carry(2), obs,
                                           jax.random.PRNGKey(3), mode="eval")
        for got, want in zip(jax.tree.leaves(jax.device_get(posts.dist)),
                             jax.tree.leaves(starts.dist), strict=True):
            np.testing.assert_allclose(got, want[:, t], atol=1e-6)

    plain, _ = acting.train_step(state, batch, jax.random.PRNGKey(4))
    trained, _ = starting.train_step(state, batch, jax.random.PRNGKey(4))
    for a, b in zip(jax.tree.leaves(plain.params["wm"]), jax.tree.leaves(trained.params["wm"]),
                    strict=True):
        np.testing.assert_array_equal(a, b)
    assert any((a != b).any() for a, b in zip(jax.tree.leaves(plain.params["actor"]),
                                              jax.tree.leaves(trained.params["actor"]),
                                              strict=True))
