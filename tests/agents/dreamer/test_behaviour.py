"""Behaviour learning (vsgjax.agents.dreamer.behaviour): λ-returns, weights, slow critic, gradients.

The world model is replaced by a tiny differentiable toy (feature = state vector) so every test
compiles in seconds; tests/agents/dreamer/test_agent.py runs the real models.
"""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vsgjax.agents.dreamer import behaviour as bhv
from vsgjax.agents.dreamer.settings import BehaviourConfig

FEAT, ACTIONS, HORIZON, GAMMA = 3, 2, 4, 0.9


def make_behaviour(discrete=False, **overrides):
    cfg = BehaviourConfig(**{"horizon": HORIZON, "gamma": GAMMA, "actor_layers": 1,
                             "critic_layers": 1, **overrides})
    return bhv.Behaviour(cfg, units=8, action_dim=ACTIONS, discrete=discrete)


def toy_world(world_params, action_gradient=1.0):
    """s_{t+1} = tanh(s_t W + a_t U); reward = s·r; γ̂ = γ·σ(s·c). Feature = state.

    ``action_gradient`` scales the gradient from the next state into the action (0 cuts it).
    """
    def rollout(policy, start, key, steps):
        def step(state, step_key):
            action = policy(state, step_key)
            fixed = jax.lax.stop_gradient(action)
            moved = fixed + action_gradient * (action - fixed)
            return jnp.tanh(state @ world_params["W"] + moved @ world_params["U"]), (state, action)

        keys = jax.random.split(key, steps + 1)
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


def test_return_weights_are_cumulative_step_discounts():
    discount = jnp.array([0.5, 0.9, 0.8])  # d_0 .. d_2 of the N = 3 steps; d_2 unused
    np.testing.assert_allclose(bhv.return_weights(discount, 1.0), [1.0, 0.5, 0.45], rtol=1e-6)
    np.testing.assert_allclose(bhv.return_weights(discount, 0.0), [0.0, 0.0, 0.0])


# A deterministic trajectory: feat_t = (t + 1)/F · 1, so the reward head (the feature sum) reads
# r_t = t + 1 and the discount head d_t = DISCOUNTS[t]; the slow critic is the constant SLOW and
# the online critic the constant ONLINE.
DISCOUNTS, SLOW, ONLINE, LAM = (0.9, 0.5, 0.8, 0.7, 0.6), 2.0, 5.0, 0.95


def counting_world():
    def rollout(policy, start, key, steps):
        feat = jnp.arange(1.0, steps + 2)[:, None] * jnp.ones(FEAT) / FEAT
        return feat, jax.vmap(policy)(feat, jax.random.split(key, steps + 1))

    def discount(feat):
        return jnp.asarray(DISCOUNTS)[jnp.round(feat.sum(-1)).astype(jnp.int32) - 1]

    return bhv.WorldFns(rollout, reward=lambda feat: feat.sum(-1), discount=discount)


def constant_critic(params, value):
    """The critic's parameters with every weight zero and the output bias ``value``."""
    critic = jax.tree.map(jnp.zeros_like, params)
    critic["Dense_1"]["bias"] = jnp.full_like(critic["Dense_1"]["bias"], value)
    return critic


@functools.partial(jax.jit, static_argnums=0)
def counting_losses(behaviour, actor, critic, slow):
    """(actor loss, (imagined, metrics)), critic loss, entropies and log-probs on one start."""
    world, starts = counting_world(), jnp.zeros((1, FEAT))
    keys = jax.random.split(jax.random.PRNGKey(5), 1)
    loss, (imagined, metrics) = bhv.actor_loss(actor, behaviour, critic, slow, world, starts,
                                               jnp.ones(1), keys)
    policy = behaviour.policy(actor, imagined.feat[0, :-1])
    critic_value = bhv.critic_loss(critic, behaviour, imagined)[0]
    return (loss, imagined, critic_value, policy.entropy(),
            policy.log_prob(imagined.action[0, :-1]))


@pytest.mark.parametrize("actor_grad", ["dynamics", "reinforce"])
def test_release_alignment_matches_a_hand_computation(actor_grad):
    """H = 4 states s_0..s_3 (3 imagined steps), 3 targets, the start's own reward in V_0."""
    behaviour = make_behaviour(alignment="release", actor_grad=actor_grad, entropy=0.01)
    params = behaviour.init(jax.random.PRNGKey(0), FEAT)
    critic, slow = (constant_critic(params["critic"], v) for v in (ONLINE, SLOW))
    loss, imagined, critic_value, entropy, log_prob = counting_losses(
        behaviour, params["actor"], critic, slow)
    assert imagined.feat.shape == (1, HORIZON, FEAT)  # the start included
    # V_2 = r_2 + d_2·((1-λ)·v_3 + λ·V_3), V_3 = v_3 = 2:  3 + 0.8·2 = 4.6
    # V_1 = 2 + 0.5·(0.05·2 + 0.95·4.6) = 4.235
    # V_0 = 1 + 0.9·(0.05·2 + 0.95·4.235) = 4.710925
    returns = np.array([4.710925, 4.235, 4.6])
    weight = np.array([1.0, 0.9, 0.9 * 0.5])  # cumprod([1, d_0, d_1])
    np.testing.assert_allclose(imagined.returns[0], returns, rtol=1e-6)
    np.testing.assert_allclose(imagined.weight[0], weight, rtol=1e-6)
    np.testing.assert_allclose(imagined.reward[0], [1.0, 2.0, 3.0], rtol=1e-6)
    if actor_grad == "dynamics":
        objective = returns
    else:  # the REINFORCE baseline is the ONLINE critic (5), not the slow one (2)
        objective = np.asarray(log_prob) * (returns - ONLINE)
    expected = -np.mean(weight * (objective + 0.01 * np.asarray(entropy)))
    np.testing.assert_allclose(loss, expected, rtol=1e-5)
    # critic: -mean(w · log N(V | 5, 1))
    expected_critic = np.mean(weight * (0.5 * (returns - ONLINE) ** 2 + 0.5 * np.log(2 * np.pi)))
    np.testing.assert_allclose(critic_value, expected_critic, rtol=1e-6)


def test_next_state_alignment_matches_a_hand_computation():
    """H = 4 imagined steps, 5 states; V_t pairs r_{t+1} and d_{t+1}; slow critic baseline."""
    behaviour = make_behaviour(alignment="next_state", actor_grad="reinforce", entropy=0.0)
    params = behaviour.init(jax.random.PRNGKey(0), FEAT)
    critic, slow = (constant_critic(params["critic"], v) for v in (ONLINE, SLOW))
    loss, imagined, _, _, log_prob = counting_losses(behaviour, params["actor"], critic, slow)
    assert imagined.feat.shape == (1, HORIZON + 1, FEAT)
    # V_3 = r_4 + d_4·v_4 = 5 + 0.6·2 = 6.2;  V_2 = 4 + 0.7·(0.1 + 0.95·6.2) = 8.193
    # V_1 = 3 + 0.8·(0.1 + 0.95·8.193) = 9.30668;  V_0 = 2 + 0.5·(0.1 + 0.95·9.30668) = 6.470673
    returns = np.array([6.470673, 9.30668, 8.193, 6.2])
    weight = np.array([1.0, 0.5, 0.5 * 0.8, 0.5 * 0.8 * 0.7])  # cumprod([1, d_1, d_2, d_3])
    np.testing.assert_allclose(imagined.returns[0], returns, rtol=1e-6)
    np.testing.assert_allclose(imagined.weight[0], weight, rtol=1e-6)
    expected = -np.mean(weight * np.asarray(log_prob) * (returns - SLOW))
    np.testing.assert_allclose(loss, expected, rtol=1e-5)


def test_conventions_agree_on_a_reward_free_trajectory_up_to_the_bootstrap_shift(world_params,
                                                                                starts):
    """No reward and a constant discount: release with H + 1 states and next_state with H steps
    imagine the same trajectory and give the same critic targets and weights."""
    world = toy_world(world_params)._replace(
        reward=lambda feat: jnp.zeros(feat.shape[:-1]),
        discount=lambda feat: jnp.full(feat.shape[:-1], GAMMA))
    release = make_behaviour(alignment="release", horizon=HORIZON + 1)
    next_state = make_behaviour(alignment="next_state", horizon=HORIZON)
    params = release.init(jax.random.PRNGKey(3), FEAT)

    @functools.partial(jax.jit, static_argnums=0)
    def imagined(behaviour):
        return bhv.actor_loss(params["actor"], behaviour, params["critic"], params["slow_critic"],
                              world, *starts)[1][0]

    a, b = imagined(release), imagined(next_state)
    np.testing.assert_array_equal(a.feat, b.feat)
    assert a.returns.shape == b.returns.shape == (5, HORIZON)
    np.testing.assert_allclose(a.returns, b.returns, rtol=1e-6)
    np.testing.assert_allclose(a.weight, b.weight, rtol=1e-6)
    assert float(jnp.abs(a.returns).max()) > 1e-3  # the slow values are not all zero


def test_start_states_drop_the_last_step_only_for_the_release_with_a_discount_head():
    posts = {"z": jnp.arange(6.0).reshape(2, 3)}
    is_terminal = jnp.array([[False, False, True], [False, True, False]])
    cases = {("release", True): ([0, 1, 3, 4], [1, 1, 1, 1]),
             ("release", False): ([0, 1, 2, 3, 4, 5], [1] * 6),
             ("next_state", True): ([0, 1, 2, 3, 4, 5], [1, 1, 0, 1, 0, 1])}
    for (alignment, drop_last), (values, continues) in cases.items():
        flat, cont = bhv.start_states(posts, is_terminal, make_behaviour(alignment=alignment),
                                      drop_last)
        np.testing.assert_array_equal(flat["z"], values)
        np.testing.assert_array_equal(cont, continues)


def test_drawn_starts_are_distinct_rows_with_their_flags_and_follow_the_key():
    starts = {"z": jnp.arange(20.0).reshape(10, 2)}
    start_continue = jnp.arange(10.0)
    drawn, cont = bhv.draw_starts(starts, start_continue, 4, jax.random.PRNGKey(0))
    rows = np.asarray(drawn["z"][:, 0] // 2).astype(int)
    assert drawn["z"].shape == (4, 2) and len(set(rows.tolist())) == 4
    np.testing.assert_array_equal(cont, rows)
    np.testing.assert_array_equal(drawn["z"][:, 1], drawn["z"][:, 0] + 1)
    again, _ = bhv.draw_starts(starts, start_continue, 4, jax.random.PRNGKey(0))
    np.testing.assert_array_equal(again["z"], drawn["z"])
    others = [bhv.draw_starts(starts, start_continue, 4, jax.random.PRNGKey(k))[0]["z"]
              for k in range(1, 4)]
    assert any(not np.array_equal(other, drawn["z"]) for other in others)


def test_release_horizon_must_leave_an_imagined_step():
    with pytest.raises(ValueError, match="ac.horizon 1 .*horizon >= 2"):
        make_behaviour(alignment="release", horizon=1)
    assert make_behaviour(alignment="next_state", horizon=1).imagined_steps == 1


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
def actor_loss(behaviour, actor, params, world_params, starts, action_gradient=1.0):
    """(loss, (imagined, metrics)) of the actor on the toy world (critics from ``params``)."""
    return bhv.actor_loss(actor, behaviour, params["critic"], params["slow_critic"],
                          toy_world(world_params, action_gradient), *starts)


@functools.partial(jax.jit, static_argnums=0)
def actor_grads(behaviour, params, world_params, starts, action_gradient):
    loss_fn = lambda actor: actor_loss(behaviour, actor, params, world_params, starts,
                                       action_gradient)[0]
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
    loss, (imagined, _) = actor_loss(behaviour, params["actor"], params, world_params, starts)
    policy = behaviour.policy(params["actor"], imagined.feat[:, :-1])
    baseline = (behaviour.value(params["critic"], imagined.feat[:, :-1]) if behaviour.release
                else imagined.slow_value[:, :-1])
    reinforce = policy.log_prob(imagined.action[:, :-1]) * (imagined.returns - baseline)
    mix = behaviour.dynamics_weight
    objective = (mix * imagined.returns + (1 - mix) * reinforce
                 + behaviour.cfg.entropy * policy.entropy())
    return loss, -jnp.mean(imagined.weight * objective)


@pytest.mark.parametrize("alignment", ["release", "next_state"])
@pytest.mark.parametrize("actor_grad", ["dynamics", "reinforce", "both"])
def test_actor_loss_values_follow_the_selected_objective(world_params, starts, actor_grad,
                                                         alignment):
    behaviour = make_behaviour(actor_grad=actor_grad, actor_grad_mix=0.25, entropy=0.01,
                               alignment=alignment)
    params = behaviour.init(jax.random.PRNGKey(3), FEAT)
    params["critic"] = jax.tree.map(lambda x: x + 0.1, params["critic"])  # online != slow
    loss, formula = actor_loss_and_formula(behaviour, params, world_params, starts)
    np.testing.assert_allclose(loss, formula, rtol=1e-5)


def test_terminal_start_states_carry_no_weight(world_params, starts):
    behaviour = make_behaviour(actor_grad="dynamics", entropy=0.01, alignment="next_state")
    params = behaviour.init(jax.random.PRNGKey(3), FEAT)
    alive = jnp.array([1.0, 0.0, 1.0, 0.0, 1.0])
    weights = [actor_loss(behaviour, params["actor"], params, world_params,
                          (starts[0], cont, starts[2]))[1][0].weight
               for cont in (jnp.ones(5), alive)]
    np.testing.assert_array_equal(weights[1], weights[0] * alive[:, None])
    assert float(weights[0].min()) > 0.0


# --- critic -------------------------------------------------------------------------------------

def test_critic_loss_trains_only_the_critic(world_params, starts):
    behaviour = make_behaviour()
    params = behaviour.init(jax.random.PRNGKey(3), FEAT)

    def loss_fn(actor, world, critic):
        _, (imagined, _) = bhv.actor_loss(actor, behaviour, critic, params["slow_critic"],
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
