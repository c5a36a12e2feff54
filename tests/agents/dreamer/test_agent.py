"""The agent (vsgjax.agents.dreamer.agent): the joint jitted update and acting, at debug size.

Each model's train_step compiles once (cached in ``_updates``) and serves every test of it.
By default VSG (continuous, dynamics backprop) and DreamerV2 (discrete, REINFORCE) run; the
other three models are marked slow (``make test`` runs them, ``make test-fast`` skips them).
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.config import make_config

BATCH, LENGTH, UPDATES, SLOW_EVERY = 2, 3, 3, 2
slow = pytest.mark.slow


def make_agent(model: str, discrete: bool, alignment: str = "release", *overrides) -> DreamerAgent:
    config = make_config("bbs_basic", model, "debug", [f"ac.slow_critic_every={SLOW_EVERY}",
                                                        f"ac.alignment={alignment}", *overrides])
    return DreamerAgent(config, (64, 64, 3), 3 if discrete else 2, discrete)


def make_batch(action_dim: int, discrete: bool, seed: int = 0) -> dict:
    """A replay-like batch: episode starts at t = 0 (and mid-sequence), one terminal step."""
    rng = np.random.default_rng(seed)
    is_first = np.zeros((BATCH, LENGTH), bool)
    is_first[:, 0] = is_first[1, 2] = True
    if discrete:
        action = np.eye(action_dim, dtype=np.float32)[rng.integers(0, action_dim, (BATCH, LENGTH))]
    else:
        action = rng.uniform(-1, 1, (BATCH, LENGTH, action_dim)).astype(np.float32)
    is_terminal = np.zeros((BATCH, LENGTH), bool)
    is_terminal[1, 1] = True
    return {
        "image": rng.integers(0, 256, (BATCH, LENGTH, 64, 64, 3), dtype=np.uint8),
        "action": np.where(is_first[..., None], 0.0, action).astype(np.float32),
        "reward": np.where(is_first, 0.0, rng.normal(size=(BATCH, LENGTH))).astype(np.float32),
        "is_first": is_first, "is_terminal": is_terminal,
    }


@functools.cache
def _updates(model: str, discrete: bool, alignment: str = "release"):
    """(agent, batch, [state_0 .. state_UPDATES], [metrics_1 .. metrics_UPDATES])."""
    agent = make_agent(model, discrete, alignment)
    batch = make_batch(agent.action_dim, discrete)
    states, metrics = [agent.init(jax.random.PRNGKey(0))], []
    for update in range(UPDATES):
        state, step_metrics = agent.train_step(states[-1], batch, jax.random.PRNGKey(100 + update))
        states.append(state)
        metrics.append(jax.device_get(step_metrics))
    return agent, batch, states, metrics


@pytest.fixture(scope="module", params=[
    ("vsg", False), ("dreamerv2", True),
    pytest.param(("svsg", False), marks=slow), pytest.param(("dreamerv1", False), marks=slow),
    pytest.param(("ssm", False), marks=slow),
], ids=lambda param: param[0])
def run(request):
    return _updates(*request.param)


def _leaves_equal(a, b) -> bool:
    return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b),
                                                     strict=True))


# --- train_step ---------------------------------------------------------------------------------

def test_train_step_gives_finite_metrics_and_updates_every_network(run):
    _, _, states, metrics = run
    for prefix in ("wm/loss", "wm/kl", "actor/loss", "actor/entropy", "critic/loss",
                   "critic/value", "imag/return", "actor/grad_norm", "critic/grad_norm"):
        assert prefix in metrics[0], sorted(metrics[0])
    for step_metrics in metrics:
        bad = {name: value for name, value in step_metrics.items() if not np.isfinite(value)}
        assert not bad, bad
    assert metrics[0]["actor/grad_norm"] > 0 and metrics[0]["critic/grad_norm"] > 0
    for name in ("wm", "actor", "critic"):
        assert not _leaves_equal(states[0].params[name], states[1].params[name]), name
    assert [int(state.step) for state in states] == list(range(UPDATES + 1))


def test_same_seed_gives_identical_state_and_metrics(run):
    agent, batch, states, metrics = run
    assert _leaves_equal(agent.init(jax.random.PRNGKey(0)), states[0])
    state, again = agent.train_step(states[0], batch, jax.random.PRNGKey(100))
    assert jax.device_get(again) == metrics[0]
    assert _leaves_equal(state, states[1])
    _, other_key = agent.train_step(states[0], batch, jax.random.PRNGKey(7))
    assert jax.device_get(other_key) != metrics[0]


def test_slow_critic_is_copied_every_period_and_held_between(run):
    """The release: update k copies the critic as it is at its start when k % 2 == 0."""
    _, _, states, _ = run
    params = [state.params for state in states]
    assert _leaves_equal(params[0]["slow_critic"], params[0]["critic"])  # initialised as a copy
    # update 0 copies the initial critic, update 1 holds, update 2 copies the critic after 2
    assert _leaves_equal(params[1]["slow_critic"], params[0]["critic"])
    assert _leaves_equal(params[2]["slow_critic"], params[0]["critic"])
    assert _leaves_equal(params[3]["slow_critic"], params[2]["critic"])
    assert not _leaves_equal(params[3]["slow_critic"], params[3]["critic"])


def test_next_state_alignment_copies_the_slow_critic_after_the_update():
    _, _, states, metrics = _updates("vsg", False, "next_state")
    params = [state.params for state in states]
    # update 0 copies its updated critic, update 1 holds, update 2 copies again
    assert _leaves_equal(params[1]["slow_critic"], params[1]["critic"])
    assert _leaves_equal(params[2]["slow_critic"], params[1]["critic"])
    assert _leaves_equal(params[3]["slow_critic"], params[3]["critic"])
    assert all(np.isfinite(value) for value in metrics[0].values())


def test_imagining_from_some_of_the_starts_trains_every_network():
    """ac.starts=3 of the batch's 4 release starts: a different update, just as complete."""
    agent = make_agent("vsg", False, "release", "ac.starts=3")
    _, batch, states, metrics = _updates("vsg", False)
    state, part = agent.train_step(states[0], batch, jax.random.PRNGKey(100))
    part = jax.device_get(part)
    assert all(np.isfinite(value) for value in part.values())
    assert part["wm/loss"] == metrics[0]["wm/loss"]  # the world model's update is unchanged
    assert part["actor/loss"] != metrics[0]["actor/loss"]
    for name in ("wm", "actor", "critic"):
        assert not _leaves_equal(states[0].params[name], state.params[name]), name


# --- policy_step --------------------------------------------------------------------------------

def _observation(seed: int, is_first) -> dict:
    rng = np.random.default_rng(seed)
    is_first = np.asarray(is_first, bool)
    return {"image": rng.integers(0, 256, (len(is_first), 64, 64, 3), dtype=np.uint8),
            "is_first": is_first}


@pytest.fixture(scope="module")
def vsg_policy():
    agent, _, states, _ = _updates("vsg", False)
    params = states[-1].params
    warm, _ = agent.policy_step(params, agent.initial_carry(2), _observation(1, [True, True]),
                                jax.random.PRNGKey(1))
    return agent, params, warm


def _env(tree, index):
    return jax.tree.map(lambda x: np.asarray(x[index]), tree)


def test_policy_step_resets_state_and_previous_action_where_is_first(vsg_policy):
    agent, params, warm = vsg_policy
    assert np.abs(warm[1]).sum() > 0 and np.abs(warm[0].deter).sum() > 0
    obs, key = _observation(2, [True, False]), jax.random.PRNGKey(2)
    from_warm = agent.policy_step(params, warm, obs, key, mode="eval")
    from_zero = agent.policy_step(params, agent.initial_carry(2), obs, key, mode="eval")
    assert _leaves_equal(_env(from_warm, 0), _env(from_zero, 0))  # env 0 starts an episode
    assert not _leaves_equal(_env(from_warm, 1), _env(from_zero, 1))  # env 1 continues


def test_eval_takes_the_actor_mode_and_train_samples_it(vsg_policy):
    agent, params, warm = vsg_policy
    obs, feat = _observation(3, [False, False]), jax.vmap(agent.world_model.dynamics.feat)
    (posts, _), action = agent.policy_step(params, warm, obs, jax.random.PRNGKey(3), mode="eval")
    mode = agent.behaviour.policy(params["actor"], feat(posts)).mode()
    np.testing.assert_allclose(action, mode, rtol=1e-6)
    (posts, _), sampled = agent.policy_step(params, warm, obs, jax.random.PRNGKey(3))
    mode = agent.behaviour.policy(params["actor"], feat(posts)).mode()
    assert sampled.shape == (2, 2) and sampled.dtype == jnp.float32
    assert float(jnp.abs(sampled).max()) <= 1.0 and not np.allclose(sampled, mode)
    _, other = agent.policy_step(params, warm, obs, jax.random.PRNGKey(4))
    assert not np.allclose(sampled, other)


def test_discrete_actions_are_one_hot_and_eval_is_the_argmax():
    agent, _, states, _ = _updates("dreamerv2", True)
    params, carry = states[-1].params, agent.initial_carry(3)
    obs = _observation(4, [True, True, False])
    (posts, _), action = agent.policy_step(params, carry, obs, jax.random.PRNGKey(5), mode="eval")
    logits = agent.behaviour.policy(params["actor"],
                                    jax.vmap(agent.world_model.dynamics.feat)(posts)).logits
    np.testing.assert_array_equal(action, jax.nn.one_hot(jnp.argmax(logits, -1), 3))
    _, sampled = agent.policy_step(params, carry, obs, jax.random.PRNGKey(5))
    np.testing.assert_array_equal(np.sort(np.asarray(sampled), -1), [[0, 0, 1]] * 3)


def test_unknown_policy_mode_is_an_error_naming_it(vsg_policy):
    agent, params, warm = vsg_policy
    with pytest.raises(ValueError, match="'greedy'"):
        agent.policy_step(params, warm, _observation(0, [False, False]), jax.random.PRNGKey(0),
                          mode="greedy")
