"""Collection: deterministic, correctly aligned transitions and episodes."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tests.support.fake_envs import FakeImageEnv
from vsgjax.agents.acting import random_policy
from vsgjax.config import make_config
from vsgjax.data.collect import Collector, EnvBatch, make_env_batch
from vsgjax.envs import EnvSpec
from vsgjax.envs.wrappers import DefaultSeed

CHUNK = 7


def fake_env(seed: int, **kwargs):
    return DefaultSeed(FakeImageEnv(**kwargs), seed)


def counting_policy(params, carry, obs, key):
    """Action depends on the key and on a per-env step counter that resets where is_first."""
    carry = jnp.where(obs["is_first"], 0, carry + 1)
    noise = jax.random.uniform(key, (carry.shape[0], 2), minval=-0.5, maxval=0.5)
    return carry, jnp.tanh(noise + params * carry[:, None])


def discrete_policy(params, carry, obs, key):
    index = jax.random.randint(key, obs["is_first"].shape, 0, 3)
    return carry, jax.nn.one_hot(index, 3)


def collect(*, seeds=(0, 1), chunks=3, workers=False, policy=counting_policy, **env_kw):
    """Run ``chunks`` chunks; return the streams, the episodes and the final carry."""
    episodes = []
    envs = EnvBatch([functools.partial(fake_env, s, **env_kw) for s in seeds], workers=workers)
    collector = Collector(envs, policy, chunk=CHUNK,
                          on_episode=lambda ep, i, info: episodes.append((ep, i, info)))
    carry = jnp.zeros(len(seeds), jnp.int32)
    streams = []
    for k in range(chunks):
        carry, stream = collector.run(jnp.float32(0.1), carry, jax.random.PRNGKey(k))
        streams.append(stream)
    collector.close()
    stream = {k: np.concatenate([s[k] for s in streams]) for k in streams[0]}
    return stream, episodes, np.asarray(carry)


def assert_same_episodes(episodes_a, episodes_b):
    assert len(episodes_a) == len(episodes_b) > 0
    for (ep_a, i_a, info_a), (ep_b, i_b, info_b) in zip(episodes_a, episodes_b, strict=True):
        assert (i_a, info_a) == (i_b, info_b)
        assert ep_a.keys() == ep_b.keys()
        for key in ep_a:
            np.testing.assert_array_equal(ep_a[key], ep_b[key], err_msg=key)


@pytest.fixture(scope="module")
def scan_run():
    return collect()


def test_collection_is_deterministic_given_seeds(scan_run):
    _, episodes, _ = scan_run
    _, episodes_again, _ = collect()
    assert_same_episodes(episodes, episodes_again)
    _, other_seeds, _ = collect(seeds=(5, 6))
    # the seeds set the fake env's episode lengths
    assert ([len(ep["reward"]) for ep, _, _ in episodes]
            != [len(ep["reward"]) for ep, _, _ in other_seeds])


def test_episodes_are_complete_and_aligned(scan_run):
    stream, episodes, _ = scan_run
    assert {i for _, i, _ in episodes} == {0, 1}
    for episode, _, info in episodes:
        t_len = len(episode["reward"])
        assert all(episode[k].shape[0] == t_len for k in episode)
        assert episode["image"].dtype == np.uint8 and episode["image"].shape[1:] == (64, 64, 3)
        assert episode["is_first"][0] and not episode["is_first"][1:].any()
        assert episode["is_terminal"][-1] and not episode["is_terminal"][:-1].any()
        np.testing.assert_array_equal(episode["action"][0], 0.0)
        assert episode["reward"][0] == 0.0
        # the fake env's image counts steps and encodes the action that led to it
        np.testing.assert_array_equal(episode["image"][:, 1, 1, 0], np.arange(t_len))
        np.testing.assert_array_equal(episode["image"][1:, 0, 0, 0],
                                      np.round(episode["action"][1:].sum(-1) * 50) % 256)
        np.testing.assert_allclose(episode["reward"][1:], episode["action"][1:].sum(-1),
                                   rtol=1e-6)
        assert info["length"] == t_len - 1 == info["fake_metric"]
        assert info["return"] == pytest.approx(episode["reward"].sum(), rel=1e-5)
    # the stream: an is_last observation is followed by the next episode's is_first
    last = stream["is_last"][:-1]
    np.testing.assert_array_equal(stream["is_first"][1:][last], True)
    assert stream["is_first"][1:][~last].sum() == 0


def test_policy_carry_sees_is_first(scan_run):
    stream, _, carry = scan_run
    # counting_policy's carry counts the observations seen since the env's last is_first; the
    # policy saw the reset observation and every streamed one but the newest
    for env in range(2):
        seen_first = np.concatenate([[True], stream["is_first"][:-1, env]])
        assert carry[env] == len(seen_first) - 1 - np.flatnonzero(seen_first)[-1]


def test_truncated_episodes_are_not_terminal():
    _, episodes, _ = collect(seeds=(0,), chunks=2, terminate=False)
    assert episodes and not any(ep["is_terminal"].any() for ep, _, _ in episodes)


def test_discrete_actions_are_one_hot_and_env_gets_the_index():
    _, episodes, _ = collect(seeds=(3,), chunks=2, policy=discrete_policy,
                             discrete=True, action_dim=3)
    for episode, _, _ in episodes:
        actions = episode["action"][1:]
        np.testing.assert_array_equal(actions.sum(-1), 1.0)
        np.testing.assert_array_equal(episode["reward"][1:], actions.argmax(-1))


def test_worker_processes_match_in_process_envs(scan_run):
    _, episodes, _ = scan_run
    _, episodes_workers, _ = collect(workers=True)
    assert_same_episodes(episodes, episodes_workers)


def test_random_policy_formats():
    obs = {"is_first": jnp.zeros(4, bool)}
    _, box = random_policy(EnvSpec((64, 64, 3), 2, False))(None, None, obs, jax.random.PRNGKey(0))
    assert box.shape == (4, 2) and float(jnp.abs(box).max()) <= 1.0 and float(box.std()) > 0
    _, hot = random_policy(EnvSpec((64, 64, 1), 6, True))(None, None, obs, jax.random.PRNGKey(0))
    np.testing.assert_array_equal(hot.sum(-1), 1.0)


def test_make_env_batch_on_a_real_task():
    env_cfg = make_config("atari_pong", size="debug").env
    envs = make_env_batch(env_cfg, seed=0, num_envs=1)
    collector = Collector(envs, random_policy(envs.spec), chunk=3)
    _, stream = collector.run(None, None, jax.random.PRNGKey(0))
    collector.close()
    assert envs.spec == EnvSpec((64, 64, 1), 6, True)
    assert stream["action"].shape == (3, 1, 6)


def test_bbs_discovery_metrics_reach_on_episode():
    env_cfg = dataclasses.replace(make_config("bbs_basic", size="debug").env, time_limit=40)
    infos = []
    envs = make_env_batch(env_cfg, seed=0, num_envs=1)
    collector = Collector(envs, random_policy(envs.spec), chunk=12,
                          on_episode=lambda ep, i, info: infos.append(info))
    collector.run(None, None, jax.random.PRNGKey(0))
    collector.close()
    assert len(infos) == 1 and infos[0]["length"] == 11  # 42 sub-steps at repeat 4
    assert infos[0]["discovery/episode_length"] == 11
    assert 0.0 <= infos[0]["discovery/never_visited"] <= 100.0


def test_reset_starts_fresh_episodes():
    envs = EnvBatch([functools.partial(fake_env, 0)])
    collector = Collector(envs, counting_policy, chunk=3)
    carry, _ = collector.run(jnp.float32(0.0), jnp.zeros(1, jnp.int32), jax.random.PRNGKey(0))
    assert int(carry[0]) == 2  # counted the reset observation as 0, then 1, 2
    collector.reset()
    carry, _ = collector.run(jnp.float32(0.0), carry, jax.random.PRNGKey(1))
    collector.close()
    assert int(carry[0]) == 2  # a fresh reset observation (is_first) restarted the count


def test_bad_arguments_are_rejected():
    envs = EnvBatch([functools.partial(fake_env, 0)])
    with pytest.raises(ValueError, match="chunk"):
        Collector(envs, counting_policy, chunk=0)
    envs.close()
