"""The optimizers (vsgjax.agents.dreamer.optim): TF's Adam epsilon, the release's weight decay,
AdamW,
clipping."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from vsgjax.agents.dreamer.optim import agent_optimizers, make_optimizer, scale_by_tf_adam
from vsgjax.agents.dreamer.settings import OptimConfig
from vsgjax.config import make_config

PARAMS = {"kernel": jnp.array([[1.1, -2.3], [0.7, 3.9]], jnp.float32),
          "bias": jnp.array([0.3, -0.05], jnp.float32)}


def run(optimizer, grads_seq, params=PARAMS):
    state = optimizer.init(params)
    for grads in grads_seq:
        updates, state = optimizer.update(grads, state, params)
        params = optax.apply_updates(params, updates)
    return params


def zeros(count):
    return [jax.tree.map(jnp.zeros_like, PARAMS)] * count


def random_grads(count, scale=1.0, seed=0):
    rng = np.random.default_rng(seed)
    return [jax.tree.map(lambda p: jnp.asarray(scale * rng.normal(size=p.shape), jnp.float32),
                         PARAMS) for _ in range(count)]


def test_release_decay_shrinks_every_parameter_by_exactly_one_minus_wd_per_update():
    """Zero gradients: Adam's step is 0, so k updates multiply kernels and biases by (1-wd)^k."""
    k = 7
    exact = run(make_optimizer(1e-3, 1e-5, 100.0, 0.25), zeros(k))
    for name, value in exact.items():  # 0.25·p is exact, so p - 0.25·p rounds like p·0.75
        expected = np.asarray(PARAMS[name])
        for _ in range(k):
            expected = expected * np.float32(0.75)
        np.testing.assert_array_equal(value, expected, err_msg=name)
    small = run(make_optimizer(1e-3, 1e-5, 100.0, 1e-3), zeros(k))
    for name, value in small.items():
        np.testing.assert_allclose(value, np.asarray(PARAMS[name], np.float64) * (1 - 1e-3) ** k,
                                   rtol=1e-6, err_msg=name)


def test_release_decay_is_not_scaled_by_the_learning_rate_and_adamw_is():
    lr, wd, k = 1e-2, 1e-3, 5
    release = run(make_optimizer(lr, 1e-5, 100.0, wd), zeros(k))
    adamw = run(make_optimizer(lr, 1e-5, 100.0, wd, OptimConfig(weight_decay="adamw")), zeros(k))
    np.testing.assert_allclose(release["kernel"], PARAMS["kernel"] * (1 - wd) ** k, rtol=1e-6)
    np.testing.assert_allclose(adamw["kernel"], PARAMS["kernel"] * (1 - lr * wd) ** k, rtol=1e-6)


def tf_adam_reference(grads_seq, lr, eps, wd, clip, b1=0.9, b2=0.999):
    """TF2's Adam (epsilon on sqrt(v)) after global-norm clipping, then var <- (1 - wd)·var."""
    params = {k: np.asarray(v, np.float64) for k, v in PARAMS.items()}
    m = {k: np.zeros_like(v) for k, v in params.items()}
    v = {k: np.zeros_like(p) for k, p in params.items()}
    for t, grads in enumerate(grads_seq, start=1):
        grads = {k: np.asarray(g, np.float64) for k, g in grads.items()}
        norm = np.sqrt(sum((g ** 2).sum() for g in grads.values()))
        grads = {k: g * min(1.0, clip / norm) for k, g in grads.items()}
        lr_t = lr * np.sqrt(1 - b2 ** t) / (1 - b1 ** t)
        for k in params:
            m[k] = b1 * m[k] + (1 - b1) * grads[k]
            v[k] = b2 * v[k] + (1 - b2) * grads[k] ** 2
            params[k] = (1 - wd) * (params[k] - lr_t * m[k] / (np.sqrt(v[k]) + eps))
    return params


@pytest.mark.parametrize("clip", [100.0, 0.5])
def test_release_optimizer_matches_tensorflow_adam_then_decay(clip):
    """A large eps (0.1) makes the placement visible: TF's effective eps, eps/sqrt(1 - β2^t),
    is ~32x larger at the first step, so its first steps are much shorter than optax's."""
    grads = random_grads(6, scale=0.2)
    ours = run(make_optimizer(1e-2, 0.1, clip, 1e-2), grads)
    reference = tf_adam_reference(grads, 1e-2, 0.1, 1e-2, clip)
    for name in PARAMS:
        np.testing.assert_allclose(ours[name], reference[name], rtol=2e-6, atol=1e-7)
    optax_eps = run(make_optimizer(1e-2, 0.1, clip, 1e-2, OptimConfig(eps_placement="optax")),
                    grads)
    moved = lambda p: np.abs(np.asarray(p["kernel"]) - np.asarray(PARAMS["kernel"]) * 0.99 ** 6)
    assert np.all(moved(ours) < 0.8 * moved(optax_eps))


def test_tf_adam_state_has_optax_adams_structure():
    ours, theirs = scale_by_tf_adam().init(PARAMS), optax.scale_by_adam().init(PARAMS)
    assert jax.tree.structure(ours) == jax.tree.structure(theirs)


def test_presets_use_the_release_rule_and_their_decay_rates():
    bbs, dmc = make_config("bbs_basic", "vsg"), make_config("dmc_walker_walk", "vsg")
    assert bbs.optim == OptimConfig("release", "release")
    assert (bbs.wm.weight_decay, bbs.ac.weight_decay) == (1e-6, 1e-6)
    assert (dmc.wm.weight_decay, dmc.ac.weight_decay) == (0.0, 0.0)
    assert set(agent_optimizers(bbs)) == {"wm", "actor", "critic"}


def test_unknown_rules_are_errors_naming_them():
    with pytest.raises(ValueError, match="'l2'.*release, adamw"):
        make_optimizer(1e-3, 1e-5, 100.0, 0.0, OptimConfig(weight_decay="l2"))
    with pytest.raises(ValueError, match="'inside'.*release, optax"):
        make_optimizer(1e-3, 1e-5, 100.0, 0.0, OptimConfig(eps_placement="inside"))
