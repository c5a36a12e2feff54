"""Behaviour learning (vsgjax.behaviour): λ-returns, weights, slow critic, actor/critic gradients.

The world model is replaced by a tiny differentiable toy (feature = state vector) so every test
compiles in seconds; tests/test_agent.py runs the real models.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vsgjax import behaviour as bhv
from vsgjax.config import BehaviourConfig

FEAT, ACTIONS, HORIZON, GAMMA = 3, 2, 4, 0.9


def make_behaviour(discrete=False, **overrides):
    cfg = BehaviourConfig(horizon=HORIZON, gamma=GAMMA, actor_layers=1, critic_layers=1,
                          **overrides)
    return bhv.Behaviour(cfg, units=8, action_dim=ACTIONS, discrete=discrete)


def toy_world(world_params, action_gradient=1.0):
    """s_{t+1} = tanh(s_t W + a_t U); reward = s·r; γ̂ = γ·σ(s·c). Feature = state.

    ``action_gradient`` scales the gradient from the next state into the action (0 cuts it).
    """
    def rollout(policy, start, key):
        def step(state, step_key):
            action = policy(state, step_key)
            fixed = jax.lax.stop_gradient(action)
            moved = fixed + action_gradient * (action - fixed)
            return jnp.tanh(state @ world_params["W"] + moved @ world_params["U"]), (state, action)

        keys = jax.random.split(key, HORIZON + 1)
        last, (states, actions) = jax.lax.scan(step, start, keys[:-1])
        last_action = policy(last, keys[-1])
        return jnp.concatenate([states, last[None]]), jnp.concatenate([actions, last_action[None]])

    return bhv.WorldFns(rollout=rollout, reward=lambda feat: feat @ world_params["r"],
                        discount=lambda feat: GAMMA * jax.nn.sigmoid(feat @ world_params["c"]))


@pytest.fixture(scope="module")
def world_params():
    keys = jax.random.split(jax.random.PRNGKey(0), 4)
    return {"W": jax.random.normal(keys[0], (FEAT, FEAT)),
            "U": jax.random.normal(keys[1], (ACTIONS, FEAT)),
            "r": jax.random.normal(keys[2], (FEAT,)), "c": jax.random.normal(keys[3], (FEAT,))}


@pytest.fixture(scope="module")
def starts():
    count = 5
    return (jax.random.normal(jax.random.PRNGKey(1), (count, FEAT)), jnp.ones(count),
            jax.random.split(jax.random.PRNGKey(2), count))


# --- returns and weights ------------------------------------------------------------------------

def test_lambda_returns_match_hand_computation():
    # reward[t] = r_{t+1}, discount[t] = γ̂_{t+1}, value[t] = v_{t+1}; V_2 bootstraps with v_3 = 30.
    reward, discount, value = jnp.array([1.0, 2, 3]), jnp.array([0.9, 0.5, 0.8]), jnp.array(
        [10.0, 20, 30])
    # V_2 = 3 + 0.8·30 = 27;  V_1 = 2 + 0.5·(0.05·20 + 0.95·27) = 15.325;
    # V_0 = 1 + 0.9·(0.05·10 + 0.95·15.325) = 14.552875
    np.testing.assert_allclose(bhv.lambda_returns(reward, discount, value, 0.95),
                               [14.552875, 15.325, 27.0], rtol=1e-6)
    # λ = 1: discounted Monte-Carlo return bootstrapped with v_3; λ = 0: one-step TD targets.
    np.testing.assert_allclose(bhv.lambda_returns(reward, discount, value, 1.0),
                               [1 + 0.9 * (2 + 0.5 * 27), 2 + 0.5 * 27, 27], rtol=1e-6)
    np.testing.assert_allclose(bhv.lambda_returns(reward, discount, value, 0.0),
                               [1 + 9, 2 + 10, 27], rtol=1e-6)


def test_lambda_returns_treat_trailing_axes_as_batch():
    rng = np.random.default_rng(0)
    reward, discount, value = (jnp.asarray(rng.random((4, 3)), jnp.float32) for _ in range(3))
    batched = bhv.lambda_returns(reward, discount, value, 0.7)
    for column in range(3):
        single = bhv.lambda_returns(reward[:, column], discount[:, column], value[:, column], 0.7)
        np.testing.assert_allclose(batched[:, column], single, rtol=1e-6)


def test_return_weights_are_shifted_cumulative_discounts():
    discount = jnp.array([0.5, 0.9, 0.8, 0.7])  # γ̂_0 .. γ̂_3 for H = 3; γ̂_0 and γ̂_3 unused
    np.testing.assert_allclose(bhv.return_weights(discount, 1.0), [1.0, 0.9, 0.72], rtol=1e-6)
    np.testing.assert_allclose(bhv.return_weights(discount, 0.0), [0.0, 0.0, 0.0])


def test_imagined_returns_skip_the_start_reward_and_bootstrap_with_the_slow_critic():
    """Deterministic states s_t = t + 1 (reward t + 1), constant γ̂ and slow value b."""
    behaviour, b = make_behaviour(), 2.0

    def rollout(policy, start, key):
        feat = jnp.arange(1.0, HORIZON + 2)[:, None] * jnp.ones(FEAT) / FEAT
        return feat, jax.vmap(policy)(feat, jax.random.split(key, HORIZON + 1))

    world = bhv.WorldFns(rollout, reward=lambda feat: feat.sum(-1),
                         discount=lambda feat: jnp.full(feat.shape[:-1], GAMMA))
    params = behaviour.init(jax.random.PRNGKey(0), FEAT)
    slow = jax.tree.map(jnp.zeros_like, params["critic"])
    slow["Dense_1"]["bias"] = jnp.full_like(slow["Dense_1"]["bias"], b)
    imagine = jax.jit(lambda actor, slow: bhv.imagine(behaviour, actor, slow, world,
                                                      jnp.zeros(FEAT), 1.0, jax.random.PRNGKey(1)))
    imagined = imagine(params["actor"], slow)
    lam, expected, following = behaviour.cfg.lam, [], b  # V_H = v_H = b
    for t in reversed(range(HORIZON)):  # V_t = r_{t+1} + γ((1-λ) b + λ V_{t+1}), r_{t+1} = t + 2
        following = (t + 2) + GAMMA * ((1 - lam) * b + lam * following)
        expected.insert(0, following)
    np.testing.assert_allclose(imagined.returns, expected, rtol=1e-5)
    np.testing.assert_allclose(imagined.weight, GAMMA ** np.arange(HORIZON), rtol=1e-6)


# --- slow critic --------------------------------------------------------------------------------

def test_slow_critic_is_copied_exactly_at_multiples_of_the_period():
    slow, seen = {"w": jnp.array(-1.0)}, []
    for step in range(8):
        critic = {"w": jnp.array(float(step))}  # the critic after update number `step`
        slow = bhv.update_slow_critic(critic, slow, jnp.array(step), every=3)
        seen.append(float(slow["w"]))
    assert seen == [0, 0, 0, 3, 3, 3, 6, 6]


# --- actor-gradient selection -------------------------------------------------------------------

@pytest.mark.parametrize("discrete, actor_grad, mix, expected", [
    (False, "auto", 0.0, 1.0), (True, "auto", 0.0, 0.0), (False, "reinforce", 0.0, 0.0),
    (True, "dynamics", 0.0, 1.0), (True, "both", 0.3, 0.3),
])
def test_actor_grad_mode_selects_dynamics_weight(discrete, actor_grad, mix, expected):
    behaviour = make_behaviour(discrete, actor_grad=actor_grad, actor_grad_mix=mix)
    assert behaviour.dynamics_weight == expected


def test_unknown_actor_grad_is_an_error_naming_it():
    with pytest.raises(ValueError, match="'backprop'"):
        make_behaviour(actor_grad="backprop")
    with pytest.raises(ValueError, match="1.5"):
        make_behaviour(actor_grad="both", actor_grad_mix=1.5)


@functools.partial(jax.jit, static_argnums=0)
def actor_loss(behaviour, actor, slow_critic, world_params, starts, action_gradient=1.0):
    """(loss, (imagined, metrics)) of the actor on the toy world."""
    return bhv.actor_loss(actor, behaviour, slow_critic, toy_world(world_params, action_gradient),
                          *starts)


@functools.partial(jax.jit, static_argnums=0)
def actor_grads(behaviour, params, world_params, starts, action_gradient):
    loss_fn = lambda actor: bhv.actor_loss(
        actor, behaviour, params["slow_critic"], toy_world(world_params, action_gradient),
        *starts)[0]
    return jax.grad(loss_fn)(params["actor"])


def _norm(tree):
    return float(jnp.sqrt(sum(jnp.sum(x ** 2) for x in jax.tree.leaves(tree))))


@pytest.mark.parametrize("discrete", [False, True])
def test_dynamics_gradient_goes_through_the_world_and_reinforce_does_not(world_params, starts,
                                                                         discrete):
    """Cutting the action → next-state path changes the dynamics gradient, not REINFORCE's."""
    params = make_behaviour(discrete).init(jax.random.PRNGKey(3), FEAT)
    for actor_grad in ("dynamics", "reinforce"):
        behaviour = make_behaviour(discrete, actor_grad=actor_grad, entropy=0.0)
        full = actor_grads(behaviour, params, world_params, starts, 1.0)
        cut = actor_grads(behaviour, params, world_params, starts, 0.0)
        assert _norm(full) > 1e-4, actor_grad
        difference = _norm(jax.tree.map(jnp.subtract, full, cut))
        if actor_grad == "dynamics":
            assert difference > 1e-4 * _norm(full)
        else:
            assert difference == 0.0


@functools.partial(jax.jit, static_argnums=0)
def actor_loss_and_formula(behaviour, params, world_params, starts):
    """The actor loss, and the same loss recomputed here from its imagined trajectory."""
    loss, (imagined, _) = actor_loss(behaviour, params["actor"], params["slow_critic"],
                                     world_params, starts)
    policy = behaviour.policy(params["actor"], imagined.feat[:, :-1])
    reinforce = policy.log_prob(imagined.action[:, :-1]) * (
        imagined.returns - imagined.slow_value[:, :-1])
    mix = behaviour.dynamics_weight
    objective = (mix * imagined.returns + (1 - mix) * reinforce
                 + behaviour.cfg.entropy * policy.entropy())
    return loss, -jnp.mean(imagined.weight * objective)


@pytest.mark.parametrize("actor_grad", ["dynamics", "reinforce", "both"])
def test_actor_loss_values_follow_the_selected_objective(world_params, starts, actor_grad):
    behaviour = make_behaviour(actor_grad=actor_grad, actor_grad_mix=0.25, entropy=0.01)
    params = behaviour.init(jax.random.PRNGKey(3), FEAT)
    loss, formula = actor_loss_and_formula(behaviour, params, world_params, starts)
    np.testing.assert_allclose(loss, formula, rtol=1e-5)


def test_terminal_start_states_carry_no_weight(world_params, starts):
    behaviour = make_behaviour(actor_grad="dynamics", actor_grad_mix=0.25, entropy=0.01)
    params = behaviour.init(jax.random.PRNGKey(3), FEAT)
    alive = jnp.array([1.0, 0.0, 1.0, 0.0, 1.0])
    weights = [actor_loss(behaviour, params["actor"], params["slow_critic"], world_params,
                          (starts[0], cont, starts[2]))[1][0].weight
               for cont in (jnp.ones(5), alive)]
    np.testing.assert_array_equal(weights[1], weights[0] * alive[:, None])
    assert float(weights[0].min()) > 0.0


# --- critic -------------------------------------------------------------------------------------

def test_critic_loss_trains_only_the_critic(world_params, starts):
    behaviour = make_behaviour()
    params = behaviour.init(jax.random.PRNGKey(3), FEAT)

    def loss_fn(actor, world, critic):
        _, (imagined, _) = bhv.actor_loss(actor, behaviour, params["slow_critic"],
                                          toy_world(world), *starts)
        return bhv.critic_loss(critic, behaviour, imagined)[0]

    actor_grad, world_grad, critic_grad = jax.jit(jax.grad(loss_fn, argnums=(0, 1, 2)))(
        params["actor"], world_params, params["critic"])
    assert _norm(actor_grad) == 0.0 and _norm(world_grad) == 0.0
    assert _norm(critic_grad) > 1e-4


def test_critic_loss_is_weighted_gaussian_regression_on_returns():
    behaviour = make_behaviour()
    critic = behaviour.init(jax.random.PRNGKey(0), FEAT)["critic"]
    feat = jax.random.normal(jax.random.PRNGKey(1), (2, HORIZON + 1, FEAT))
    returns = jax.random.normal(jax.random.PRNGKey(2), (2, HORIZON))
    weight = jnp.linspace(0.1, 1.0, 2 * HORIZON).reshape(2, HORIZON)
    imagined = bhv.Imagined(feat, None, None, None, None, returns, weight)
    value = behaviour.value(critic, feat[:, :-1])
    expected = jnp.mean(weight * (0.5 * (returns - value) ** 2 + 0.5 * np.log(2 * np.pi)))
    np.testing.assert_allclose(bhv.critic_loss(critic, behaviour, imagined)[0], expected,
                               rtol=1e-5)


# --- action distributions -----------------------------------------------------------------------

def test_truncated_normal_actions_stay_in_bounds_with_squashed_mean_and_min_std():
    behaviour = make_behaviour(actor_min_std=0.1)
    actor = behaviour.init(jax.random.PRNGKey(0), FEAT)["actor"]
    feat = 10.0 * jax.random.normal(jax.random.PRNGKey(1), (256, FEAT))

    @jax.jit
    def sample_mode_std_logp(actor, feat):
        policy = behaviour.policy(actor, feat)
        sample = policy.sample(jax.random.PRNGKey(2))
        return sample, policy.mode(), policy.std, policy.log_prob(sample)

    sample, mode, std, log_prob = sample_mode_std_logp(actor, feat)
    assert sample.shape == (256, ACTIONS)
    assert float(jnp.abs(sample).max()) <= 1.0 - bhv.TRUNC_CLIP
    assert float(jnp.abs(mode).max()) <= 1.0
    assert float(std.min()) >= 0.1 and float(std.max()) <= 2.1
    assert bool(jnp.all(jnp.isfinite(log_prob)))


def test_one_hot_actions_sample_one_hot_with_straight_through_gradient():
    logits = jnp.array([[0.0, 1.0, -1.0], [2.0, 0.0, 0.0]])
    policy = bhv.OneHotActions(logits)
    sample = policy.sample(jax.random.PRNGKey(0))
    np.testing.assert_array_equal(sample.sum(-1), [1.0, 1.0])
    assert set(np.unique(np.asarray(sample)).tolist()) <= {0.0, 1.0}
    np.testing.assert_array_equal(policy.mode(), [[0, 1, 0], [1, 0, 0]])
    # d sample[0, 0] / d logits = d softmax[0, 0] / d logits (straight-through)
    grad = jax.grad(lambda x: bhv.OneHotActions(x).sample(jax.random.PRNGKey(0))[0, 0])(logits)
    expected = jax.grad(lambda x: jax.nn.softmax(x)[0, 0])(logits)
    np.testing.assert_allclose(grad, expected, rtol=1e-6)


def test_truncated_normal_agrees_with_tfp():
    """log_prob and entropy exactly, sample moments and reparameterised gradients statistically."""
    from tensorflow_probability.substrates import jax as tfp

    mean = jnp.array([-1.0, -0.7, 0.0, 0.5, 1.0])
    std = jnp.array([0.1, 0.5, 1.0, 2.1, 0.3])
    action = jnp.array([-0.99, -0.5, 0.0, 0.7, 0.95])
    reference = lambda m, s: tfp.distributions.TruncatedNormal(m, s, -1.0, 1.0)
    ours = bhv.TruncNormalActions(mean[:, None], std[:, None])
    np.testing.assert_allclose(ours.log_prob(action[:, None]),
                               reference(mean, std).log_prob(action), rtol=1e-4, atol=1e-5)
    np.testing.assert_allclose(ours.entropy(), reference(mean, std).entropy(),
                               rtol=1e-4, atol=1e-5)

    count = 20_000

    @jax.jit
    def sample_mean(m, s):
        shape = (count, m.shape[0])
        policy = bhv.TruncNormalActions(jnp.broadcast_to(m, shape), jnp.broadcast_to(s, shape))
        return policy.sample(jax.random.PRNGKey(0)).mean(0)

    moments, (grad_mean, grad_std) = sample_mean(mean, std), jax.jacfwd(sample_mean, (0, 1))(
        mean, std)
    np.testing.assert_allclose(moments, reference(mean, std).mean(), atol=0.02)
    step = 1e-2  # central differences of TFP's analytic mean
    diff = lambda dm, ds: (reference(mean + dm, std + ds).mean()
                           - reference(mean - dm, std - ds).mean()) / (2 * step)
    np.testing.assert_allclose(jnp.diagonal(grad_mean), diff(step, 0.0), atol=0.05)
    np.testing.assert_allclose(jnp.diagonal(grad_std), diff(0.0, step), atol=0.05)
