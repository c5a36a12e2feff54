"""Vector observations: the observation spec, the MLP encoder/decoder, mixed image + vector."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tests.support.registry_names import models
from vsgjax.agents.dreamer import api
from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.agents.dreamer.world_model import WorldModel, obs_spec_of
from vsgjax.config import ConfigError, make_config
from vsgjax.observations import ObsSpec, obs_spec
from vsgjax.registry.tasks import VECTOR as VECTOR_KIND

TASK = "dmc_walker_walk"
VECTOR = {"vector": (24,)}
MIXED = {"image": (64, 64, 3), "vector": (24,)}


def config(model: str = "vsg", overrides=()):
    return make_config(TASK, model, "debug", overrides)


def random_batch(spec: ObsSpec, batch: int = 2, length: int = 6, action_dim: int = 6,
                 seed: int = 0) -> dict:
    """A [B, T] batch with the spec's keys, an episode start mid-sequence."""
    rng = np.random.default_rng(seed)
    is_first = np.zeros((batch, length), bool)
    is_first[:, [0, length // 2]] = True
    out = {"action": rng.uniform(-1, 1, (batch, length, action_dim)).astype(np.float32),
           "reward": rng.normal(size=(batch, length)).astype(np.float32),
           "is_first": is_first, "is_terminal": np.zeros((batch, length), bool)}
    for key, shape in spec.entries:
        out[key] = (rng.integers(0, 256, (batch, length, *shape), np.uint8)
                    if spec.dtype(key) == np.uint8
                    else rng.normal(size=(batch, length, *shape)).astype(np.float32))
    return out


# --- the spec ---------------------------------------------------------------------------------

def test_spec_constructors_agree_and_sort_their_keys():
    image = ObsSpec.from_image_shape((64, 64, 3))
    assert image == obs_spec((64, 64, 3)) == obs_spec({"image": [64, 64, 3]}) == obs_spec(image)
    mixed = ObsSpec.from_dict({"vector": (24,), "image": (64, 64, 3)})
    assert mixed.keys == ("image", "vector") and mixed == obs_spec(MIXED)
    assert hash(mixed) == hash(obs_spec(MIXED))
    assert mixed.image_keys == ("image",) and mixed.vector_keys == ("vector",)
    two = obs_spec({"velocity": (3,), "position": (5,)})
    assert two.vector_keys == ("position", "velocity") and two.vector_size == 8
    assert mixed.dtype("image") == np.uint8 and mixed.dtype("vector") == np.float32


@pytest.mark.parametrize("shapes, match", [
    ({"vector": (4, 4)}, r"'vector' has shape \(4, 4\): want rank 3"),
    ({"vector": (0,)}, r"'vector' has shape \(0,\).*positive"),
    ({"vector": "abc"}, r"'vector' has shape 'abc'"),
    ({"reward": (3,)}, r"'reward' is taken by the batch"),
    ({"my-key": (3,)}, r"'my-key' must be a Python identifier"),
    ({}, "at least one key"),
])
def test_bad_specs_name_the_key_and_what_is_valid(shapes, match):
    with pytest.raises(ValueError, match=match):
        obs_spec(shapes)


def test_spec_checks_observations():
    spec = obs_spec(MIXED)
    assert spec.check({"image": np.zeros((2, 5, 64, 64, 3)), "vector": np.zeros((2, 5, 24)),
                       "is_first": np.zeros((2, 5))}) == (2, 5)
    with pytest.raises(ValueError, match="lack key 'vector'"):
        spec.check({"image": np.zeros((2, 64, 64, 3))})
    with pytest.raises(ValueError, match=r"'vector' has shape \(2, 23\)"):
        spec.check({"image": np.zeros((2, 64, 64, 3)), "vector": np.zeros((2, 23))})
    with pytest.raises(ValueError, match="leading dims"):
        spec.check({"image": np.zeros((2, 64, 64, 3)), "vector": np.zeros((3, 24))})


def test_the_world_model_rejects_what_its_encoders_cannot_encode():
    with pytest.raises(ConfigError, match=r"wm.encoder=cnn cannot encode the vector keys.*"
                                          r"'vector' \(24,\)"):
        WorldModel(config(overrides=["wm.encoder=cnn"]), VECTOR)
    with pytest.raises(ConfigError, match=r"wm.encoder=mlp cannot encode the image keys"):
        WorldModel(config(overrides=["wm.encoder=mlp"]), MIXED)
    with pytest.raises(ConfigError, match="valid: auto, cnn, mlp"):
        config(overrides=["wm.encoder=transformer"])
    with pytest.raises(ValueError, match=r"one image, under key 'image'.*\['pixels'\]"):
        WorldModel(config(), {"pixels": (64, 64, 3)})
    with pytest.raises(ValueError, match=r"'image' has shape \(32, 32, 3\)"):
        WorldModel(config(), {"image": (32, 32, 3)})
    assert WorldModel(config(overrides=["wm.encoder=mlp"]), VECTOR).embed_size == 32
    assert WorldModel(config(overrides=["wm.encoder=cnn"]), (64, 64, 1)).obs_shape.keys == (
        "image",)


def test_params_name_their_spec_and_an_image_shape_is_the_image_spec():
    spec = obs_spec({"image": (64, 64, 1), "position": (5,), "velocity": (3,)})
    params = jax.eval_shape(WorldModel(config(), spec, 6).init, jax.random.PRNGKey(0))
    assert obs_spec_of(params) == spec
    assert set(params) == {"encoder", "decoder", "mlp_encoder", "mlp_decoder", "dynamics",
                           "reward"}
    image = WorldModel(config(), (64, 64, 3), 6)
    assert image == WorldModel(config(), {"image": (64, 64, 3)}, 6)
    params = jax.eval_shape(image.init, jax.random.PRNGKey(0))
    assert "mlp_encoder" not in params and obs_spec_of(params) == image.obs_shape
    pixels = jax.ShapeDtypeStruct((2, 64, 64, 3), jnp.uint8)
    assert jax.eval_shape(image.encode, params, pixels).shape == (2, image.embed_size)
    with pytest.raises(ValueError, match="lack key 'image'"):
        jax.eval_shape(image.encode, params, {"vector": jnp.zeros((2, 24))})


# --- training and acting ---------------------------------------------------------------------

@pytest.mark.parametrize("model", models(gated=True, observes=VECTOR_KIND))
def test_agent_trains_on_vector_observations(model):
    agent = DreamerAgent(config(model), VECTOR, 6, False)
    state = agent.init(jax.random.PRNGKey(0))
    wm = state.params["wm"]
    assert "decoder" not in wm and "encoder" not in wm and "mlp_decoder" in wm
    state, metrics = agent.train_step(state, random_batch(agent.obs_shape),
                                      jax.random.PRNGKey(1))
    assert all(np.isfinite(v).all() for v in jax.tree.leaves(metrics))
    assert "wm/vector_mse" in metrics and "wm/image_mse" not in metrics
    assert "wm/gate_loss" in metrics and int(state.step) == 1


def test_mixed_observations_train_both_decoders():
    cfg = config()
    state = api.init(cfg, jax.random.PRNGKey(0), obs_shape=MIXED, action_dim=6)
    batch = random_batch(obs_spec(MIXED))
    new, metrics, posts = api.world_model_step(cfg, state, batch, jax.random.PRNGKey(1))
    assert {"image_mse", "vector_mse", "image_loss", "vector_loss"} <= set(metrics)
    parts = sum(metrics[k] for k in ("image_loss", "vector_loss", "reward_loss", "kl_loss",
                                     "gate_loss"))
    np.testing.assert_allclose(metrics["loss"], parts, rtol=1e-6)
    for name in ("decoder", "mlp_decoder", "encoder", "mlp_encoder"):
        moved = jax.tree.map(lambda a, b: np.abs(a - b).max(), new.params[name],
                             state.params[name])
        assert max(jax.tree.leaves(moved)) > 0, name
    last = jax.tree.map(lambda x: x[:, -1], posts)
    out = api.imagine(new.params, last, 3, config=cfg, action_dim=6)
    assert out["images"].shape == (2, 3, 64, 64, 3) and out["vectors"]["vector"].shape == (
        2, 3, 24)


def test_policy_step_on_vector_observations():
    agent = DreamerAgent(config(), VECTOR, 6, False)
    params = agent.init(jax.random.PRNGKey(0)).params
    obs = {"vector": jnp.ones((3, 24)), "is_first": jnp.ones(3, bool)}
    carry, action = agent.policy_step(params, agent.initial_carry(3), obs, jax.random.PRNGKey(1))
    assert action.shape == (3, 6) and np.all(np.abs(action) <= 1)
    _, action = agent.policy_step(params, carry, dict(obs, is_first=jnp.zeros(3, bool)),
                                  jax.random.PRNGKey(2), mode="eval")
    assert np.isfinite(action).all()
    with pytest.raises(ValueError, match="lack key 'vector'"):
        agent.policy_step(params, carry, {"image": jnp.zeros((3, 64, 64, 3), jnp.uint8),
                                          "is_first": obs["is_first"]}, jax.random.PRNGKey(3))
