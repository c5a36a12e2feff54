"""Public API: init, the jitted world-model train_step, observe and imagine (jit / vmap)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vsgjax
from vsgjax.agents.dreamer import api
from vsgjax.agents.dreamer.dynamics import make_dynamics
from vsgjax.config import make_config

CONFIG = make_config("bbs_basic", "vsg", "debug", ["wm.lr=1e-3"])
DYNAMICS = make_dynamics(CONFIG.model, CONFIG.agent)
H = 3


def random_batch(seed: int, batch: int = 2, length: int = 5):
    rng = np.random.default_rng(seed)
    is_first = np.zeros((batch, length), bool)
    is_first[:, 0] = True
    return {
        "image": rng.integers(0, 256, (batch, length, 64, 64, 3), dtype=np.uint8),
        "action": rng.uniform(-1, 1, (batch, length, 2)).astype(np.float32),
        "reward": rng.normal(size=(batch, length)).astype(np.float32),
        "is_first": is_first,
        "is_terminal": np.zeros((batch, length), bool),
    }


@pytest.fixture(scope="module")
def trained():
    """Eight updates on one fixed batch: (states after each update, metrics of each, posts)."""
    batch = random_batch(0)
    state = api.init(CONFIG, jax.random.PRNGKey(0))
    states, history = [state], []
    for step in range(8):
        state, metrics, posts = api.world_model_step(CONFIG, state, batch, jax.random.PRNGKey(step))
        states.append(state)
        history.append(metrics)
    return batch, states, history, posts


def test_init_defaults_and_state_structure():
    state = vsgjax.init(CONFIG, jax.random.PRNGKey(0))
    assert set(state.params) == {"encoder", "dynamics", "decoder", "reward", "discount"}
    assert state.step == 0
    again = api.init(CONFIG, jax.random.PRNGKey(0))
    jax.tree.map(np.testing.assert_array_equal, state.params, again.params)


def test_train_step_reduces_the_loss_on_a_fixed_batch(trained):
    _, states, history, _ = trained
    losses = [float(m["loss"]) for m in history]
    assert all(np.isfinite(losses))
    assert losses[-1] < losses[0] - 1.0, losses
    assert int(states[-1].step) == 8
    assert history[0]["grad_norm"] > 0


def test_train_step_is_deterministic_given_the_key(trained):
    batch, states, history, posts = trained
    again, metrics, again_posts = api.world_model_step(CONFIG, states[-2], batch,
                                                       jax.random.PRNGKey(7))
    jax.tree.map(np.testing.assert_array_equal, again.params, states[-1].params)
    jax.tree.map(np.testing.assert_array_equal, metrics, history[-1])
    jax.tree.map(np.testing.assert_array_equal, again_posts, posts)


def test_observe_matches_the_posteriors_of_train_step(trained):
    batch, states, _, posts = trained
    observed, priors = api.observe(CONFIG, states[-2].params, batch, jax.random.PRNGKey(7))
    jax.tree.map(lambda a, b: np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-5),
                 observed, posts)
    assert priors.deter.shape == posts.deter.shape == (2, 5, CONFIG.model.deter)


def test_imagine_shapes_for_batched_starts(trained):
    _, states, _, posts = trained
    params = states[-1].params
    starts = jax.tree.map(lambda x: x[None, :, -1], posts)  # leading dims [1, 2]
    out = api.imagine(params, starts, H, config=CONFIG, key=jax.random.PRNGKey(0), action_dim=2)
    feat_dim = CONFIG.model.deter + CONFIG.model.stoch * CONFIG.model.classes
    assert out["images"].shape == (1, 2, H, 64, 64, 3) and out["images"].dtype == jnp.uint8
    assert out["image_means"].shape == (1, 2, H, 64, 64, 3)
    assert out["feats"].shape == (1, 2, H, feat_dim)
    assert out["actions"].shape == (1, 2, H, 2) and not out["actions"].any()
    assert out["rewards"].shape == out["discounts"].shape == (1, 2, H)
    assert out["states"].deter.shape == (1, 2, H, CONFIG.model.deter)
    assert ((out["discounts"] > 0) & (out["discounts"] < 1)).all()


def test_imagine_open_loop_actions_and_policy(trained):
    _, states, _, posts = trained
    params, last = states[-1].params, jax.tree.map(lambda x: x[:, -1], posts)
    actions = jnp.ones((2, H, 2)) * 0.5
    out = api.imagine(params, last, H, config=CONFIG, key=jax.random.PRNGKey(1), actions=actions)
    np.testing.assert_array_equal(out["actions"], actions)
    assert out["images"].shape == (2, H, 64, 64, 3)

    def policy(feat, key):
        return jnp.tanh(feat[:2]) + 0.1 * jax.random.normal(key, (2,))

    out = api.imagine(params, last, H, config=CONFIG, key=jax.random.PRNGKey(1), policy=policy)
    chosen_in = jnp.concatenate([jax.vmap(DYNAMICS.feat)(last)[:, None], out["feats"][:, :-1]], 1)
    noise = out["actions"] - jnp.tanh(chosen_in[..., :2])
    assert np.abs(noise).max() < 0.6 and np.abs(noise).max() > 0
    with pytest.raises(ValueError, match="horizon"):
        api.imagine(params, last, H + 1, config=CONFIG, key=jax.random.PRNGKey(1),
                    actions=actions)
    with pytest.raises(ValueError, match="action_dim"):
        api.imagine(params, last, H, config=CONFIG, key=jax.random.PRNGKey(1))


def test_imagine_under_vmap_equals_a_loop(trained):
    _, states, _, posts = trained
    params, last = states[-1].params, jax.tree.map(lambda x: x[:, -1], posts)
    keys = jax.random.split(jax.random.PRNGKey(2), 2)

    def one(start, key):
        return api.imagine(params, start, H, config=CONFIG, key=key, action_dim=2)["feats"]

    batched = jax.jit(jax.vmap(one))(last, keys)
    for i in range(2):
        single = one(jax.tree.map(lambda x, i=i: x[i], last), keys[i])
        np.testing.assert_allclose(batched[i], single, rtol=1e-5, atol=1e-5)
