"""Task parsing, DMC pixels, Atari preprocessing and the agent-facing env contract."""

import dataclasses

import gymnasium
import numpy as np
import pytest

from vsgjax.config import make_config
from vsgjax.envs import EnvSpec, TaskError, env_spec, make_env, parse_task
from vsgjax.envs.dmc import DMCEnv


def env_config(task, **changes):
    return dataclasses.replace(make_config(task, size="paper").env, **changes)


@pytest.mark.parametrize("task, parsed", [
    ("dmc_walker_walk", ("dmc", ("walker", "walk"))),
    ("dmc_ball_in_cup_catch", ("dmc", ("ball_in_cup", "catch"))),
    ("dmc_cartpole_swingup_sparse", ("dmc", ("cartpole", "swingup_sparse"))),
    ("atari_pong", ("atari", ("pong",))),
    ("atari_space_invaders", ("atari", ("space_invaders",))),
    ("bbs_basic", ("bbs", ("basic",))),
    ("bbs_large_d4", ("bbs", ("large_d4",))),
])
def test_parse_valid_tasks(task, parsed):
    assert parse_task(task) == parsed


@pytest.mark.parametrize("task, listed", [
    ("walker_walk", "dmc_<domain>_<task>"),
    ("dmc", "atari_<game>"),
    ("dmc_walker_fly", "dmc_walker_walk"),
    ("dmc_walker", "dmc_cartpole_swingup"),
    ("atari_notagame", "atari_pong"),
    ("bbs_huge", "bbs_medium_d2"),
])
def test_unknown_tasks_list_what_is_valid(task, listed):
    with pytest.raises(TaskError) as error:
        parse_task(task)
    assert repr(task) in str(error.value) and listed in str(error.value)


@pytest.fixture(scope="module", params=["dmc_walker_walk", "dmc_cartpole_swingup"])
def dmc_rollout(request):
    env = make_env(env_config(request.param), seed=0)
    images = [env.reset()[0]]
    infos = []
    for _ in range(3):
        image, reward, terminated, truncated, info = env.step(env.action_space.sample())
        images.append(image)
        infos.append(info)
        assert isinstance(reward, float) and not terminated and not truncated
    spec = env_spec(env)
    env.close()
    return request.param, images, infos, spec


def test_dmc_images_are_64x64_rgb_and_change(dmc_rollout):
    _, images, _, spec = dmc_rollout
    assert spec.obs_shape == (64, 64, 3) and not spec.discrete
    for image in images:
        assert image.shape == (64, 64, 3) and image.dtype == np.uint8
        assert image.std() > 5.0
    assert any(not np.array_equal(images[0], im) for im in images[1:])


def test_dmc_action_repeat_counts_env_steps(dmc_rollout):
    _, _, infos, _ = dmc_rollout
    assert [info["env_steps"] for info in infos] == [2, 4, 6]


def test_dmc_time_limit_gives_500_agent_steps(monkeypatch):
    """1000 env steps at action repeat 2 (rendering stubbed out: only the step logic matters)."""
    monkeypatch.setattr(DMCEnv, "_render", lambda self: np.zeros((64, 64, 3), np.uint8))
    env = make_env(env_config("dmc_cartpole_swingup"), seed=0)
    env.reset()
    steps, done = 0, False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.zeros(1, np.float32))
        steps, done = steps + 1, terminated or truncated
    env.close()
    assert (steps, terminated, truncated) == (500, False, True)


def test_dmc_is_deterministic_given_the_seed():
    def first_images(seed):
        env = make_env(env_config("dmc_cartpole_swingup"), seed=seed)
        images = [env.reset()[0], env.step(np.full(1, 0.5, np.float32))[0]]
        env.close()
        return images

    same, again, other = first_images(1), first_images(1), first_images(2)
    np.testing.assert_array_equal(np.stack(same), np.stack(again))
    assert not np.array_equal(same[0], other[0])


@pytest.fixture(scope="module")
def pong():
    env = make_env(env_config("atari_pong"), seed=0)
    yield env
    env.close()


def test_atari_pong_is_grayscale_discrete_and_sticky(pong):
    assert env_spec(pong) == EnvSpec((64, 64, 1), 6, True)
    assert isinstance(pong.action_space, gymnasium.spaces.Discrete)
    assert pong.unwrapped.ale.getFloat("repeat_action_probability") == pytest.approx(0.25)
    image, _ = pong.reset()
    assert image.shape == (64, 64, 1) and image.dtype == np.uint8 and image.std() > 0
    frames = []
    for action in (0, 2, 3):
        image, reward, terminated, truncated, info = pong.step(action)
        frames.append(info["episode_frame_number"])
    assert np.diff(frames).tolist() == [4, 4]  # action repeat 4


def test_atari_time_limit_is_27k_agent_steps(pong):
    assert pong.get_wrapper_attr("_max_episode_steps") == 27_000


def test_atari_is_deterministic_given_the_seed():
    def frames(seed):
        env = make_env(env_config("atari_pong"), seed=seed)
        out = [env.reset()[0]] + [env.step(a)[0] for a in (2, 3, 2, 2, 3) * 8]
        env.close()
        return np.stack(out)

    np.testing.assert_array_equal(frames(4), frames(4))


def test_eval_envs_use_other_seeds():
    train = make_env(env_config("dmc_cartpole_swingup"), seed=0)
    evaluation = make_env(env_config("dmc_cartpole_swingup"), seed=0, eval=True)
    assert not np.array_equal(train.reset()[0], evaluation.reset()[0])
    train.close()
    evaluation.close()


def test_bad_config_values_are_named():
    with pytest.raises(ValueError, match="got 0, 108000, 64"):
        make_env(env_config("atari_pong", action_repeat=0), seed=0)
    with pytest.raises(ValueError, match="grayscale=True"):
        make_env(env_config("dmc_walker_walk", grayscale=True), seed=0)


def test_env_spec_rejects_non_image_observations():
    env = gymnasium.make("CartPole-v1")
    with pytest.raises(TypeError, match="uint8"):
        env_spec(env)


def test_all_16_bbs_variants_parse():
    sizes, distractors = ("basic", "small", "medium", "large"), ("", "_d1", "_d2", "_d4")
    for task in (f"bbs_{s}{d}" for s in sizes for d in distractors):
        assert parse_task(task)[0] == "bbs"


def test_bbs_basic_contract_and_751_step_episodes():
    env = make_env(env_config("bbs_basic"), seed=0)
    assert env_spec(env) == EnvSpec((64, 64, 3), 2, False)
    assert env.action_space == gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
    image, _ = env.reset()
    assert image.shape == (64, 64, 3) and image.dtype == np.uint8 and image.std() > 0
    steps, done, sub_steps = 0, False, []
    while not done:
        _, _, terminated, truncated, info = env.step(np.array([1.0, -1.0], np.float32))
        steps, done = steps + 1, terminated or truncated
        sub_steps.append(info["sub_steps"])
    env.close()
    assert sub_steps[:3] == [4, 8, 12]  # action repeat 4, done inside the env
    assert (steps, truncated) == (751, True)
