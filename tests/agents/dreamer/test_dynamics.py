"""Latent dynamics (every Dreamer-family model) and latent distributions."""

import dataclasses
import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vsgjax.agents.dreamer.distributions import Categorical, Gaussian, LatentSpace
from vsgjax.agents.dreamer.dynamics import (
    GatedRSSMState,
    RSSMState,
    SSMState,
    SVSGState,
    make_dynamics,
)
from vsgjax.config import make_config
from vsgjax.registry.agents import dreamer_models

B, T, E, A, H = 3, 6, 10, 2, 4
STATE_TYPES = {
    "dreamerv1": RSSMState, "dreamerv2": RSSMState, "vsg": GatedRSSMState,
    "svsg": SVSGState, "ssm": SSMState, "dreamerpro": RSSMState, "vsgpro": GatedRSSMState,
}


def _leaves_equal(a, b):
    return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b),
                                                    strict=True))


def _policy_params(feat_dim):
    return jax.random.normal(jax.random.PRNGKey(7), (feat_dim, A)) / np.sqrt(feat_dim)


class Setup:
    """One model at debug size, a batch of inputs and three jitted functions, built once.

    Compilation dominates the run time, so the unbatched ``observe`` is compiled only as part
    of its gradient, and ``imagine`` and ``rollout`` share one compiled function.
    """

    def __init__(self, name):
        self.name = name
        self.dyn = dyn = make_dynamics(make_config("bbs_basic", name, "debug").model, name)
        keys = jax.random.split(jax.random.PRNGKey(0), 5)
        self.params = dyn.init(keys[0], E, A)
        self.embeds = jax.random.normal(keys[1], (B, T, E))
        self.actions = jax.random.uniform(keys[2], (B, T, A), minval=-1, maxval=1)
        self.is_first = jnp.zeros((B, T), bool).at[:, 0].set(True).at[1, 3].set(True)
        self.keys = jax.random.split(keys[3], B)
        self.observe_batch = jax.jit(jax.vmap(dyn.observe, in_axes=(None, 0, 0, 0, 0)))
        self.posts, self.priors = self.observe_batch(
            self.params, self.embeds, self.actions, self.is_first, self.keys
        )
        weights = _policy_params(dyn.feat_dim)
        self.policy = lambda feat, key: jnp.tanh(feat @ weights)

        def loss(params, embeds, actions, is_first, key):
            posts, priors = dyn.observe(params, embeds, actions, is_first, key)
            kl = jax.vmap(dyn.kl)(posts, priors).sum()
            return kl + jnp.square(jax.vmap(dyn.feat)(posts)).sum(), (posts, priors)

        self.observe_grad = jax.jit(jax.grad(loss, has_aux=True))

        def imagine_and_rollout(params, start, actions, key):
            imagined = dyn.imagine(params, self.policy, start, H, key)
            return imagined, dyn.rollout(params, start, actions, key)

        self.imagine_and_rollout = jax.jit(imagine_and_rollout)

    def observe(self, b, embeds=None, actions=None):
        """Unbatched observe of example ``b`` (optionally with other inputs): (grads, states)."""
        embeds = self.embeds[b] if embeds is None else embeds
        actions = self.actions[b] if actions is None else actions
        return self.observe_grad(self.params, embeds, actions, self.is_first[b], self.keys[b])

    def start(self, b=0, t=-1):
        return jax.tree.map(lambda x: x[b, t], self.posts)


@functools.cache
def _setup(name):
    return Setup(name)


@pytest.fixture(scope="module", params=dreamer_models())
def setup(request):
    return _setup(request.param)


def test_observe_shapes(setup):
    dyn, posts, priors, cfg = setup.dyn, setup.posts, setup.priors, setup.dyn.cfg
    assert type(posts) is STATE_TYPES[setup.name] and type(priors) is STATE_TYPES[setup.name]
    stoch_shape = (cfg.stoch, cfg.classes) if cfg.classes else (cfg.stoch,)
    assert posts.stoch.shape == priors.stoch.shape == (B, T, *stoch_shape)
    if hasattr(posts, "deter"):
        assert posts.deter.shape == (B, T, cfg.deter)
    feats = jax.vmap(jax.vmap(dyn.feat))(posts)
    assert feats.shape == (B, T, dyn.feat_dim)
    kl = jax.vmap(jax.vmap(dyn.kl))(posts, priors)
    assert kl.shape == (B, T, cfg.stoch)
    assert np.all(np.asarray(kl) >= -1e-5) and np.isfinite(np.asarray(kl)).all()
    assert jax.vmap(jax.vmap(dyn.entropy))(posts).shape == (B, T)
    if dyn.gated:
        gate, prob = jax.vmap(jax.vmap(dyn.gates))(posts)
        units = cfg.deter if type(posts) is GatedRSSMState else cfg.stoch  # VSG's gate h
        assert gate.shape == prob.shape == (B, T, units)
        assert set(np.unique(np.asarray(gate))) == {0.0, 1.0}
        assert np.all((np.asarray(prob) > 0) & (np.asarray(prob) < 1))
    else:
        with pytest.raises(ValueError, match="no gates"):
            dyn.gates(dyn.initial())


def test_initial_state_is_zero_and_matches_state_structure(setup):
    initial = setup.dyn.initial()
    assert all(np.all(np.asarray(x) == 0) for x in jax.tree.leaves(initial))
    step_shapes = jax.tree.map(lambda x: x.shape[2:], setup.posts)
    assert jax.tree.map(jnp.shape, initial) == step_shapes


def test_imagine_and_rollout_shapes_alignment_and_determinism(setup):
    dyn, start = setup.dyn, setup.start()
    actions = jnp.linspace(-1, 1, H * A).reshape(H, A)
    key = jax.random.PRNGKey(1)
    (states, policy_actions), rolled = setup.imagine_and_rollout(setup.params, start, actions, key)
    assert type(states) is type(rolled) is STATE_TYPES[setup.name]
    assert all(x.shape[0] == H + 1 for x in jax.tree.leaves(states))
    assert all(x.shape[0] == H for x in jax.tree.leaves(rolled))
    assert policy_actions.shape == (H + 1, A)
    assert _leaves_equal(jax.tree.map(lambda x: x[0], states), start)
    feats = jax.vmap(dyn.feat)(states)
    np.testing.assert_allclose(policy_actions, setup.policy(feats, None), rtol=1e-5, atol=1e-6)
    assert not np.allclose(np.asarray(feats[1]), np.asarray(feats[0]))
    assert np.isfinite(np.asarray(jax.vmap(dyn.feat)(rolled))).all()
    again = setup.imagine_and_rollout(setup.params, start, actions, key)
    assert _leaves_equal(again, ((states, policy_actions), rolled))


def test_same_key_same_result_different_key_different_samples(setup):
    args = (setup.params, setup.embeds, setup.actions, setup.is_first)
    posts, priors = setup.observe_batch(*args, setup.keys)
    assert _leaves_equal((posts, priors), (setup.posts, setup.priors))
    other, _ = setup.observe_batch(*args, jax.random.split(jax.random.PRNGKey(99), B))
    assert not np.array_equal(other.stoch, posts.stoch)
    # the first posterior's distribution depends only on the inputs, not on the key
    np.testing.assert_allclose(
        jax.tree.leaves(other.dist)[0][:, 0], jax.tree.leaves(posts.dist)[0][:, 0], rtol=1e-6
    )


def test_vmap_over_batch_equals_per_example_loop(setup):
    for b in range(B):
        _, (posts, priors) = setup.observe(b)
        batched = jax.tree.map(lambda x, b=b: x[b], (setup.posts, setup.priors))
        for x, y in zip(jax.tree.leaves((posts, priors)), jax.tree.leaves(batched), strict=True):
            np.testing.assert_allclose(x, y, rtol=1e-5, atol=1e-5)


def test_is_first_resets_state_and_previous_action(setup):
    """With is_first[3], steps from 3 on ignore everything before (same key, same samples)."""
    b = 1  # this example has is_first at t = 0 and t = 3
    changed_embeds = setup.embeds[b].at[:3].set(5.0)
    changed_actions = setup.actions[b].at[:4].set(0.9)  # includes the action at t = 3
    _, changed = setup.observe(b, changed_embeds, changed_actions)
    original = jax.tree.map(lambda x: x[b], (setup.posts, setup.priors))
    for x, y in zip(jax.tree.leaves(changed), jax.tree.leaves(original), strict=True):
        np.testing.assert_allclose(x[3:], y[3:], rtol=1e-5, atol=1e-6)
    # ...while the steps before the reset did see the change
    pairs = zip(jax.tree.leaves(changed), jax.tree.leaves(original), strict=True)
    assert not all(np.allclose(x[1:3], y[1:3]) for x, y in pairs)


def test_gradients_reach_every_parameter_and_are_finite(setup):
    grads, _ = setup.observe(0)
    for path, g in jax.tree_util.tree_leaves_with_path(grads):
        g = np.asarray(g)
        assert np.isfinite(g).all(), path
        assert np.abs(g).max() > 0, path


def test_vsg_posterior_reuses_the_prior_gate():
    setup = _setup("vsg")
    np.testing.assert_array_equal(setup.posts.gate, setup.priors.gate)
    np.testing.assert_array_equal(setup.posts.deter, setup.priors.deter)
    assert not np.array_equal(setup.posts.stoch, setup.priors.stoch)
    # closed units of the deterministic state are copied bit for bit across time
    continuing = ~np.asarray(setup.is_first[:, 1:])[..., None]
    closed = (np.asarray(setup.posts.gate[:, 1:]) == 0) & continuing
    deter = np.asarray(setup.posts.deter)
    assert closed.sum() > 0
    np.testing.assert_array_equal(deter[:, 1:][closed], deter[:, :-1][closed])


def test_svsg_closed_gates_copy_the_previous_latent_exactly():
    setup = _setup("svsg")
    posts, priors = setup.posts, setup.priors
    prev = np.asarray(posts.stoch[:, :-1])
    continuing = ~np.asarray(setup.is_first[:, 1:])[..., None]
    closed = (np.asarray(posts.gate[:, 1:]) == 0) & continuing
    np.testing.assert_array_equal(np.asarray(priors.gate), np.asarray(posts.gate))
    assert closed.sum() > 0 and (~closed & continuing).sum() > 0
    for states in (posts, priors):
        np.testing.assert_array_equal(np.asarray(states.stoch[:, 1:])[closed], prev[closed])
        assert not np.any(np.asarray(states.stoch[:, 1:])[~closed & continuing]
                          == np.broadcast_to(prev, closed.shape)[~closed & continuing])


def test_make_dynamics_rejects_bad_configs():
    model = make_config("bbs_basic", "vsg", "debug").model
    with pytest.raises(ValueError, match="'lstm'.*dreamerv1"):
        make_dynamics(model, "lstm")
    with pytest.raises(ValueError, match="model.classes=4"):
        make_dynamics(model, "svsg")
    with pytest.raises(ValueError, match="model.deter must be positive"):
        make_dynamics(dataclasses.replace(model, deter=0), "vsg")
    with pytest.raises(ValueError, match="gate_mode 'soft'"):
        make_dynamics(dataclasses.replace(model, gate_mode="soft"), "vsg")
    with pytest.raises(ValueError, match="classes must be 0"):
        make_dynamics(dataclasses.replace(model, classes=1), "vsg")


def test_dynamics_is_hashable_and_equal_for_equal_configs():
    cfg = make_config("bbs_basic", "vsg", "debug").model
    assert hash(make_dynamics(cfg, "vsg")) == hash(make_dynamics(cfg, "vsg"))
    assert make_dynamics(cfg, "vsg") == make_dynamics(dataclasses.replace(cfg), "vsg")


# --- distributions ----------------------------------------------------------------------------


def test_gaussian_from_raw_std_and_kl_closed_form():
    space = LatentSpace(stoch=3, classes=0, min_std=0.1)
    raw = jnp.array([0.5, -1.0, 2.0, 0.0, -4.0, 3.0])
    dist = space.from_raw(raw)
    np.testing.assert_allclose(dist.mean, [0.5, -1.0, 2.0])
    np.testing.assert_allclose(dist.std, 2 / (1 + np.exp(-np.array([0.0, -4, 3]) / 2)) + 0.1,
                               rtol=1e-6)
    other = Gaussian(jnp.array([0.0, 1.0, -1.0]), jnp.array([1.0, 0.5, 2.0]))
    m1, s1, m2, s2 = (np.asarray(v, np.float64) for v in (*dist, *other))
    expected = np.log(s2 / s1) + (s1**2 + (m1 - m2) ** 2) / (2 * s2**2) - 0.5
    np.testing.assert_allclose(dist.kl(other), expected, rtol=1e-5)
    np.testing.assert_allclose(dist.entropy(), np.sum(0.5 * np.log(2 * np.pi * np.e * s1**2)),
                               rtol=1e-5)


def test_categorical_sample_is_one_hot_with_straight_through_gradient():
    logits = jax.random.normal(jax.random.PRNGKey(0), (4, 5))
    key = jax.random.PRNGKey(1)
    sample = Categorical(logits).sample(key)
    assert set(np.unique(np.asarray(sample))) == {0.0, 1.0}
    np.testing.assert_array_equal(np.asarray(sample).sum(-1), np.ones(4))
    weights = jnp.arange(20.0).reshape(4, 5)
    grad = jax.grad(lambda lg: (Categorical(lg).sample(key) * weights).sum())(logits)
    softmax_grad = jax.grad(lambda lg: (jax.nn.softmax(lg) * weights).sum())(logits)
    np.testing.assert_allclose(grad, softmax_grad, rtol=1e-5, atol=1e-6)


def test_categorical_kl_and_entropy_closed_form_and_finite_when_saturated():
    space = LatentSpace(stoch=2, classes=3)
    post = space.from_raw(jnp.array([1.0, 0.0, -1.0, 2.0, 2.0, 0.0]))
    prior = Categorical(jnp.zeros((2, 3)))
    p = np.asarray(jax.nn.softmax(post.logits), np.float64)
    np.testing.assert_allclose(post.kl(prior), (p * np.log(p * 3)).sum(-1), rtol=1e-5)
    np.testing.assert_allclose(post.entropy(), -(p * np.log(p)).sum(), rtol=1e-5)
    saturated = Categorical(jnp.array([[1e4, -1e4, 0.0], [-1e4, -1e4, 1e4]]))
    values = [saturated.kl(prior), prior.kl(saturated), saturated.entropy(),
              jax.grad(lambda lg: Categorical(lg).kl(prior).sum())(saturated.logits)]
    assert all(np.isfinite(np.asarray(v)).all() for v in values)


def test_threshold_gate_mode_makes_vsg_gates_deterministic():
    cfg = dataclasses.replace(make_config("bbs_basic", "vsg", "debug").model, gate_mode="threshold")
    dyn = make_dynamics(cfg, "vsg")
    params = dyn.init(jax.random.PRNGKey(0), E, A)
    prev, action = dyn.initial(), jnp.ones(A)
    step = jax.jit(dyn.img_step)
    first, second = step(params, prev, action, jax.random.PRNGKey(1)), step(
        params, prev, action, jax.random.PRNGKey(2))
    np.testing.assert_array_equal(first.gate, second.gate)
    np.testing.assert_array_equal(first.deter, second.deter)
    np.testing.assert_array_equal(first.gate, np.asarray(first.gate_logit) > 0)
    assert not np.array_equal(first.stoch, second.stoch)  # the latent is still sampled


def test_latent_space_sizes_and_flatten():
    gaussian, categorical = LatentSpace(5, 0), LatentSpace(3, 4)
    assert (gaussian.stats_dim, gaussian.flat_dim) == (10, 5)
    assert (categorical.stats_dim, categorical.flat_dim) == (12, 12)
    sample = jnp.arange(24.0).reshape(2, 3, 4)
    np.testing.assert_array_equal(categorical.flatten(sample), sample.reshape(2, 12))
    np.testing.assert_array_equal(categorical.from_raw(jnp.arange(12.0)).mode()[:, -1], 1.0)
