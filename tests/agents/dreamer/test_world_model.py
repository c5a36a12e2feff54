"""World model: networks, the KL-balanced / masked / free-nats loss, vmap, determinism, sizes."""

import distrax
import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tests.support.registry_names import models
from vsgjax.agents.dreamer.distributions import Categorical, Gaussian
from vsgjax.agents.dreamer.dynamics import RSSMState, SVSGState, make_dynamics
from vsgjax.agents.dreamer.networks import (
    MLP,
    ConvDecoder,
    ConvEncoder,
    bernoulli_log_prob,
    conv_stride2,
    conv_transpose_stride2,
    embed_dim,
    float_to_image,
    image_to_float,
    normal_log_prob,
)
from vsgjax.agents.dreamer.representation.reconstruction import gaussian_mse
from vsgjax.agents.dreamer.world_model import WorldModel, balanced_kl_loss, per_step_kl
from vsgjax.config import make_config
from vsgjax.registry.agents import dreamer_models, prototype_models


def random_batch(seed: int, batch: int, length: int, obs_shape=(64, 64, 3), action_dim: int = 2):
    """A replay-style [B, T] batch with an episode start mid-sequence and one terminal step."""
    rng = np.random.default_rng(seed)
    is_first = np.zeros((batch, length), bool)
    is_first[:, 0] = True
    is_first[:, length // 2] = True
    is_terminal = np.zeros((batch, length), bool)
    is_terminal[:, length // 2 - 1] = True
    action = rng.uniform(-1, 1, (batch, length, action_dim)).astype(np.float32)
    action[is_first] = 0.0
    return {
        "image": rng.integers(0, 256, (batch, length, *obs_shape), dtype=np.uint8),
        "action": action,
        "reward": rng.normal(size=(batch, length)).astype(np.float32),
        "is_first": is_first,
        "is_terminal": is_terminal,
    }


@pytest.fixture(scope="module")
def vsg():
    model = WorldModel(make_config("bbs_basic", "vsg", "debug"))
    return model, jax.jit(model.init)(jax.random.PRNGKey(0)), random_batch(0, 2, 6)


@pytest.fixture(scope="module")
def vsg_loss(vsg):
    model, _, _ = vsg
    return jax.jit(model.loss)


# --- networks -------------------------------------------------------------------------------

def _output_shape(module, x):
    variables = jax.eval_shape(module.init, jax.random.PRNGKey(0), x)
    return jax.eval_shape(module.apply, variables, x).shape


def test_encoder_and_decoder_shapes():
    depth = 4
    image = jax.ShapeDtypeStruct((3, 64, 64, 1), jnp.float32)
    assert _output_shape(ConvEncoder(depth), image) == (3, 32 * depth) == (3, embed_dim(depth))
    feat = jax.ShapeDtypeStruct((2, 5, 7), jnp.float32)
    assert _output_shape(ConvDecoder(depth, channels=1), feat) == (2, 5, 64, 64, 1)
    assert _output_shape(MLP(2, 8), feat) == (2, 5)
    assert _output_shape(MLP(2, 8, out_shape=(3, 4)), feat) == (2, 5, 3, 4)


@pytest.mark.parametrize("kernel_size, size, out", [(5, 1, 5), (5, 5, 5), (6, 13, 5), (6, 2, 5),
                                                    (6, 13, 1), (5, 6, 1)])
def test_phase_decomposed_transposed_conv_equals_lax_conv_transpose(kernel_size, size, out):
    """Both phase paths: im2col (many outputs) and overlap-add (1x1 input or few outputs)."""
    x = jax.random.normal(jax.random.PRNGKey(0), (2, 3, size, size, 4))
    kernel = jax.random.normal(jax.random.PRNGKey(1), (kernel_size, kernel_size, 4, out))
    # lax.conv_transpose (flax ConvTranspose) correlates with the kernel: flip it.
    reference = nn.ConvTranspose(out, (kernel_size, kernel_size), strides=(2, 2), padding="VALID")
    want = reference.apply({"params": {"kernel": kernel[::-1, ::-1], "bias": jnp.zeros(out)}}, x)
    got = conv_transpose_stride2(x, kernel)
    assert got.shape == (2, 3, 2 * size - 2 + kernel_size, 2 * size - 2 + kernel_size, out)
    np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-4)


@pytest.mark.parametrize("size", [64, 31, 6])
def test_im2col_strided_conv_equals_lax_conv(size):
    x = jax.random.normal(jax.random.PRNGKey(0), (2, 3, size, size, 4))
    kernel = jax.random.normal(jax.random.PRNGKey(1), (4, 4, 4, 5))
    reference = nn.Conv(5, (4, 4), strides=(2, 2), padding="VALID")
    want = reference.apply({"params": {"kernel": kernel, "bias": jnp.zeros(5)}}, x)
    np.testing.assert_allclose(conv_stride2(x, kernel), want, rtol=1e-5, atol=1e-4)


def test_image_scaling_round_trips():
    pixels = jnp.arange(256, dtype=jnp.uint8)
    scaled = image_to_float(pixels)
    assert scaled.min() == -0.5 and scaled.max() == 0.5
    np.testing.assert_array_equal(float_to_image(scaled), pixels)
    assert float_to_image(jnp.array([-3.0, 3.0])).tolist() == [0, 255]


def test_log_probs_match_distrax():
    mean, target = jnp.array([[0.3, -1.0], [2.0, 0.5]]), jnp.array([[0.0, 1.0], [1.5, 0.5]])
    np.testing.assert_allclose(normal_log_prob(mean, target, event_dims=1),
                               distrax.Normal(mean, 1.0).log_prob(target).sum(-1), rtol=1e-6)
    logits = jnp.array([-40.0, -1.0, 0.0, 3.0, 40.0])
    for value in (0.0, 1.0):
        np.testing.assert_allclose(bernoulli_log_prob(logits, value),
                                   distrax.Bernoulli(logits=logits).log_prob(value), atol=1e-6)
    assert np.isfinite(bernoulli_log_prob(jnp.array([1e4, -1e4]), 0.5)).all()


# --- KL balancing, free nats, masking ---------------------------------------------------------

def _categorical_states(key, length=3, stoch=4, classes=5):
    post_key, prior_key = jax.random.split(key)

    def state(logits):
        return RSSMState(jnp.zeros((length, 8)), jnp.zeros((length, stoch, classes)),
                         Categorical(logits))

    post_logits = jax.random.normal(post_key, (length, stoch, classes))
    prior_logits = jax.random.normal(prior_key, (length, stoch, classes))
    return state, post_logits, prior_logits


def test_kl_balancing_splits_gradients_between_prior_and_posterior():
    dyn = make_dynamics(make_config("bbs_basic", "dreamerv2", "debug").model, "dreamerv2")
    state, post_logits, prior_logits = _categorical_states(jax.random.PRNGKey(1))
    sg = jax.lax.stop_gradient

    def balanced(post_logits, prior_logits):
        post, prior = state(post_logits), state(prior_logits)
        kl_rep = per_step_kl(dyn, post, jax.tree.map(sg, prior)).mean()
        kl_dyn = per_step_kl(dyn, jax.tree.map(sg, post), prior).mean()
        return balanced_kl_loss(kl_rep, kl_dyn, scale=1.0, balance=0.8, free=0.0)

    def plain(post_logits, prior_logits):
        return per_step_kl(dyn, state(post_logits), state(prior_logits)).mean()

    value = balanced(post_logits, prior_logits)
    np.testing.assert_allclose(value, plain(post_logits, prior_logits), rtol=1e-6)
    d_post, d_prior = jax.grad(balanced, argnums=(0, 1))(post_logits, prior_logits)
    g_post, g_prior = jax.grad(plain, argnums=(0, 1))(post_logits, prior_logits)
    assert np.abs(g_post).max() > 1e-3 and np.abs(g_prior).max() > 1e-3
    np.testing.assert_allclose(d_post, 0.2 * g_post, rtol=1e-5, atol=1e-7)
    np.testing.assert_allclose(d_prior, 0.8 * g_prior, rtol=1e-5, atol=1e-7)


def test_free_nats_clamp_the_batch_mean():
    kl = jnp.array(0.7)
    assert balanced_kl_loss(kl, kl, 2.0, 0.8, free=1.0) == 2.0
    assert jax.grad(balanced_kl_loss, argnums=(0, 1))(kl, kl, 2.0, 0.8, 1.0) == (0.0, 0.0)
    grads = jax.grad(balanced_kl_loss, argnums=(0, 1))(kl, kl, 2.0, 0.8, 0.5)
    np.testing.assert_allclose(grads, (0.4, 1.6), rtol=1e-6)


def _svsg_states(key, gate, length=3, dims=6):
    keys = jax.random.split(key, 4)

    def state(mean_key, std_key):
        dist = Gaussian(jax.random.normal(mean_key, (length, dims)),
                        0.5 + jax.random.uniform(std_key, (length, dims)))
        return SVSGState(jnp.zeros((length, dims)), dist, gate, jnp.zeros((length, dims)))

    return state(keys[0], keys[1]), state(keys[2], keys[3])


def test_masked_kl_is_zero_when_every_gate_is_closed():
    dyn = make_dynamics(make_config("bbs_basic", "svsg", "debug").model, "svsg")
    closed = jnp.zeros((3, 6))
    post, prior = _svsg_states(jax.random.PRNGKey(2), closed)
    np.testing.assert_array_equal(per_step_kl(dyn, post, prior, mask=closed), 0.0)
    per_dim = jax.vmap(dyn.kl)(post, prior)
    assert per_step_kl(dyn, post, prior).min() > 0
    # The mask passes gradient into the gate: d(masked KL)/dg = the per-dimension KL.
    np.testing.assert_allclose(
        jax.grad(lambda g: per_step_kl(dyn, post, prior, mask=g).sum())(closed), per_dim,
        rtol=1e-6)
    some_open = closed.at[:, :2].set(1.0)
    np.testing.assert_allclose(per_step_kl(dyn, post, prior, mask=some_open),
                               per_dim[:, :2].sum(-1), rtol=1e-6)


def test_masked_kl_needs_one_gate_per_latent_dimension(vsg):
    _, params, batch = vsg
    config = make_config("bbs_basic", "vsg", "debug", ["wm.kl_masked=true"])
    with pytest.raises(ValueError, match="svsg"):
        jax.eval_shape(WorldModel(config).loss, params, batch, jax.random.PRNGKey(0))


# --- the loss over a batch --------------------------------------------------------------------

def test_loss_is_the_sum_of_its_terms_and_reports_every_metric(vsg, vsg_loss):
    model, params, batch = vsg
    loss, (metrics, posts) = vsg_loss(params, batch, jax.random.PRNGKey(3))
    terms = ("image_loss", "reward_loss", "discount_loss", "kl_loss", "gate_loss")
    np.testing.assert_allclose(loss, sum(metrics[t] for t in terms), rtol=1e-6)
    expected = {"kl", "kl_prior_post", "post_entropy", "prior_entropy", "gate_kl",
                "gate_units_per_step_mean", "gate_units_per_step_std",
                "gate_updates_per_unit_mean", "gate_updates_per_unit_std", "gate_prob_mean"}
    assert expected <= set(metrics)
    assert all(np.isfinite(v) for v in metrics.values())
    # free nats 0, balance splits an identical value: kl_loss = kl_scale * KL
    np.testing.assert_allclose(metrics["kl_loss"], model.config.wm.kl_scale * metrics["kl"],
                               rtol=1e-6)
    assert posts.deter.shape == (2, 6, model.config.model.deter)
    assert 0.0 < metrics["gate_prob_mean"] < 1.0


def test_same_key_same_loss_other_key_other_loss(vsg, vsg_loss):
    _, params, batch = vsg
    first = vsg_loss(params, batch, jax.random.PRNGKey(4))
    again = vsg_loss(params, batch, jax.random.PRNGKey(4))
    other = vsg_loss(params, batch, jax.random.PRNGKey(5))
    jax.tree.map(np.testing.assert_array_equal, first, again)
    assert first[0] != other[0]


def test_vmap_over_the_batch_equals_a_per_example_loop(vsg):
    model, params, batch = vsg
    keys = jax.random.split(jax.random.PRNGKey(6), 2)
    batched, _ = jax.jit(jax.vmap(model.sequence_terms, in_axes=(None, 0, 0)))(params, batch, keys)
    single = jax.jit(model.sequence_terms)
    for i in range(2):
        terms, _ = single(params, jax.tree.map(lambda x, i=i: x[i], batch), keys[i])
        for name, value in terms.items():
            np.testing.assert_allclose(batched[name][i], value, rtol=2e-5, atol=2e-4,
                                       err_msg=name)


def test_episode_start_resets_the_state(vsg):
    """After is_first the posterior must not depend on what came before it."""
    model, params, batch = vsg
    seq = jax.tree.map(lambda x: x[0], batch)
    changed = dict(seq, image=seq["image"].copy())
    changed["image"][:3] = 255 - changed["image"][:3]
    observe = jax.jit(model.observe)
    a, _ = observe(params, seq, jax.random.PRNGKey(7))
    b, _ = observe(params, changed, jax.random.PRNGKey(7))
    assert not np.allclose(a.deter[2], b.deter[2])
    np.testing.assert_allclose(a.deter[3:], b.deter[3:], rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("name", [m for m in dreamer_models()
                                  if m != "vsg" and m not in prototype_models()])
def test_loss_finite_for_every_model_at_debug_size(name):
    """(The prototype models' loss needs the agent's EMA targets: test_dreamerpro.py.)"""
    model = WorldModel(make_config("bbs_basic", name, "debug"))
    params = jax.jit(model.init)(jax.random.PRNGKey(0))
    loss, (metrics, _) = jax.jit(model.loss)(params, random_batch(1, 2, 4), jax.random.PRNGKey(1))
    assert np.isfinite(loss) and all(np.isfinite(v) for v in metrics.values())
    assert ("gate_loss" in metrics) == model.dynamics.gated


@pytest.mark.slow
@pytest.mark.parametrize("size", ["small", "paper"])
@pytest.mark.parametrize("name", models(gated=True, prototypes=False))
def test_loss_finite_at_larger_sizes(name, size):
    model = WorldModel(make_config("bbs_basic", name, size))
    params = jax.jit(model.init)(jax.random.PRNGKey(0))
    loss, _ = jax.jit(model.loss)(params, random_batch(2, 1, 2), jax.random.PRNGKey(1))
    assert np.isfinite(loss)


def test_heads_without_discount_and_with_tanh_reward():
    config = make_config("atari_pong", "dreamerv2", "debug", ["wm.discount_head=false"])
    model = WorldModel(config, obs_shape=(64, 64, 1), action_dim=4)
    params = jax.eval_shape(model.init, jax.random.PRNGKey(0))
    assert "discount" not in params and config.wm.reward_tanh
    feat = jnp.zeros((5, model.dynamics.feat_dim))
    np.testing.assert_allclose(model.discount(params, feat), np.full(5, config.ac.gamma))
    assert jax.eval_shape(model.representation.decode, params, feat).shape == (5, 64, 64, 1)
    batch = random_batch(3, 1, 3, obs_shape=(64, 64, 1), action_dim=4)
    _, (metrics, _) = jax.eval_shape(model.loss, params, batch, jax.random.PRNGKey(0))
    assert "discount_loss" not in metrics and "reward_loss" in metrics


def test_obs_shape_is_checked():
    with pytest.raises(ValueError, match=r"\(32, 32, 3\)"):
        WorldModel(make_config(size="debug"), obs_shape=(32, 32, 3))


def test_image_mse_recovers_the_squared_error_from_the_gaussian_image_loss():
    rng = np.random.default_rng(0)
    mean, target = rng.uniform(-0.5, 0.5, (2, 4, 64, 64, 3)).astype(np.float32)
    loss = -normal_log_prob(mean, target, event_dims=3).mean()
    np.testing.assert_allclose(gaussian_mse(loss, 64 * 64 * 3), np.square(mean - target).mean(),
                               rtol=1e-3)


def test_decode_frames_in_chunks_equals_one_decode():
    model = WorldModel(make_config("bbs_basic", "vsg", "debug"))
    params = model.init(jax.random.PRNGKey(0))
    feats = jax.random.normal(jax.random.PRNGKey(1), (3, 5, model.dynamics.feat_dim))
    decoder = model.representation
    np.testing.assert_allclose(decoder.decode_frames(params, feats, chunk=4),
                               decoder.decode(params, feats), atol=1e-5)


@pytest.mark.parametrize("alignment", ["release", "next_state"])
def test_discount_head_target_and_prediction_follow_the_alignment(alignment):
    """release: trained on γ·(1 − terminal) and used as it is; next_state: on 1 − terminal, ×γ."""
    config = make_config("bbs_basic", "vsg", "debug", [f"ac.alignment={alignment}",
                                                        "ac.gamma=0.9"])
    model = WorldModel(config)
    params = jax.jit(model.init)(jax.random.PRNGKey(0))
    feat = jax.random.normal(jax.random.PRNGKey(1), (4, model.dynamics.feat_dim))
    prob = jax.nn.sigmoid(model.discount_logits(params, feat))
    target = model.discount_target(jnp.array([False, True]))
    if alignment == "release":
        np.testing.assert_allclose(target, [0.9, 0.0], rtol=1e-6)
        np.testing.assert_allclose(model.discount(params, feat), prob, rtol=1e-6)
    else:
        np.testing.assert_allclose(target, [1.0, 0.0])
        np.testing.assert_allclose(model.discount(params, feat), 0.9 * prob, rtol=1e-6)
