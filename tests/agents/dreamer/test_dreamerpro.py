"""DreamerPro and VSGPro (the ``prototypes`` models) inside the Dreamer agent: their presets
against the authors' ``configs.yaml`` (fdeng18/dreamer-pro, ``DreamerPro/dreamerv2/
configs.yaml``: ``defaults`` then ``dmc``), and the update of ``DreamerPro/dreamerv2/agent.py``
(``WorldModel.train``: prototypes normalised before the loss and frozen for the first updates,
the EMA targets copied at the first update and mixed after it, two augmented views). The
equations of the prototype losses are tested in ``test_prototypes.py``.
"""

import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from tests.support.doc_tables import cell_value, config_value, table_rows
from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.agents.dreamer.open_loop import open_loop_errors, open_loop_video
from vsgjax.agents.dreamer.representation import prototype_losses as prototypes
from vsgjax.config import ConfigError, make_config, to_dict
from vsgjax.registry.agents import prototype_models

BATCH, LENGTH, UPDATES, ACTIONS = 2, 4, 3, 2
TASK = "dmc_walker_run"


@pytest.mark.parametrize("model", prototype_models())
def test_presets_are_the_authors_dmc_settings(model):
    """``defaults`` + ``dmc`` of the authors' configs.yaml (rssm, kl, dataset, optimisers,
    action repeat, prototypes; sinkhorn_eps 0.0125 in the dmc block)."""
    config = make_config(TASK, model, "paper")
    m, wm, ac, train, proto = config.model, config.wm, config.ac, config.train, config.proto
    assert (m.deter, m.hidden, m.stoch, m.classes) == (200, 200, 32, 0)
    assert (wm.kl_free, wm.kl_balance, wm.kl_scale, wm.discount_head) == (1.0, 0.8, 1.0, False)
    assert (wm.cnn_depth, wm.reward_layers, wm.mlp_units, wm.lr) == (48, 4, 400, 3e-4)
    assert (wm.reward_scale, wm.weight_decay, ac.weight_decay) == (1.0, 1e-6, 1e-6)
    # actor_grad "auto" is the dynamics gradient for continuous actions (the dmc block's)
    assert (ac.actor_lr, ac.critic_lr, ac.entropy, ac.actor_grad) == (8e-5, 8e-5, 1e-4, "auto")
    assert (ac.actor_layers, ac.critic_layers, ac.horizon) == (4, 4, 15)
    assert (train.batch, train.length, train.train_every) == (50, 51, 5)
    assert (train.prefill, train.pretrain, config.env.action_repeat) == (5000, 100, 2)
    assert (proto.prototypes, proto.dim, proto.temperature) == (2500, 32, 0.1)
    assert (proto.sinkhorn_eps, proto.sinkhorn_iters, proto.warm_up) == (0.0125, 3, 1)
    assert (proto.freeze_updates, proto.ema_fraction, proto.shift) == (10_000, 0.05, 3.0)
    # the release's GRU has LayerNorm; VSG's gated cell (VSGPro's) has none
    assert m.cell_norm is (model == "dreamerpro")
    assert make_config("bbs_basic", model, "paper").proto.sinkhorn_eps == 0.05


@pytest.mark.parametrize("model", prototype_models())
def test_a_vector_task_is_refused_naming_it(model):
    with pytest.raises(ConfigError, match="'mjx_walker_walk'.*image observations"):
        make_config("mjx_walker_walk", model, "cpu")


def test_prototype_keys_are_refused_by_reconstruction_models():
    with pytest.raises(ConfigError, match="'proto.dim' is not read by model 'dreamerv2'"):
        make_config(TASK, "dreamerv2", "debug", ["proto.dim=8"])


def test_warm_up_must_leave_a_step():
    with pytest.raises(ConfigError, match="proto.warm_up.*train.length=4"):
        make_config(TASK, "dreamerpro", "debug", ["proto.warm_up=4", "train.length=4"])


def make_batch(seed: int = 0) -> dict:
    rng = np.random.default_rng(seed)
    is_first = np.zeros((BATCH, LENGTH), bool)
    is_first[:, 0] = True
    return {"image": rng.integers(0, 256, (BATCH, LENGTH, 64, 64, 3), dtype=np.uint8),
            "action": rng.uniform(-1, 1, (BATCH, LENGTH, ACTIONS)).astype(np.float32),
            "reward": rng.normal(size=(BATCH, LENGTH)).astype(np.float32),
            "is_first": is_first, "is_terminal": np.zeros((BATCH, LENGTH), bool)}


@functools.cache
def _updates(model: str):
    """(agent, batch, [state_0 .. state_UPDATES], [metrics_1 ..]): prototypes frozen for the
    first update only."""
    config = make_config(TASK, model, "debug", ["proto.prototypes=16", "proto.freeze_updates=1",
                                                f"train.length={LENGTH}"])
    agent = DreamerAgent(config, (64, 64, 3), ACTIONS, False)
    batch = make_batch()
    states, metrics = [agent.init(jax.random.PRNGKey(0))], []
    for update in range(UPDATES):
        state, step_metrics = agent.train_step(states[-1], batch, jax.random.PRNGKey(7 + update))
        states.append(state)
        metrics.append(jax.device_get(step_metrics))
    return agent, batch, states, metrics


@pytest.fixture(scope="module", params=prototype_models())
def updates(request):
    return _updates(request.param)


def test_parameters_have_prototypes_and_targets_but_no_decoder(updates):
    agent, _, states, _ = updates
    wm = states[0].params["wm"]
    assert "decoder" not in wm and "mlp_decoder" not in wm
    assert wm["proto"]["prototypes"].shape == (16, 32)
    assert set(states[0].params["wm_targets"]) == {"encoder", "obs_proj"}


def test_targets_copy_the_online_networks_at_the_first_update_then_mix(updates):
    """agent.py ``WorldModel.ema_update``: mix 1.0 at update 0, ``ema_update_fraction`` (0.05)
    after; after the optimizer step."""
    _, _, states, _ = updates
    online = lambda state: {"encoder": state.params["wm"]["encoder"],
                            "obs_proj": state.params["wm"]["proto"]["obs_proj"]}
    before = states[0].params["wm_targets"]
    pairs = lambda x, y: zip(jax.tree.leaves(x), jax.tree.leaves(y), strict=True)
    assert any(not np.allclose(a, b) for a, b in pairs(before, online(states[0])))
    for a, b in pairs(states[1].params["wm_targets"], online(states[1])):
        np.testing.assert_array_equal(a, b)
    expected = jax.tree.map(lambda o, t: 0.05 * o + 0.95 * t, online(states[2]),
                            states[1].params["wm_targets"])
    for a, b in pairs(states[2].params["wm_targets"], expected):
        np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-7)


def test_prototypes_are_normalised_and_frozen_for_the_first_updates(updates):
    """nets.py ``RSSM.proto_loss`` assigns the L2-normalised prototypes; agent.py
    ``WorldModel.train`` zeroes their gradient while updates < freeze_prototypes_iters (here
    1). What remains of update 1 is the release's weight decay, (1 - 1e-6)."""
    _, _, states, _ = updates
    proto = lambda state: np.asarray(state.params["wm"]["proto"]["prototypes"])
    normalised = np.asarray(prototypes.l2_normalize(proto(states[0])))
    assert not np.allclose(proto(states[0]), normalised)
    np.testing.assert_allclose(proto(states[1]), (1 - 1e-6) * normalised, rtol=1e-6)
    step = np.abs(proto(states[2]) - np.asarray(prototypes.l2_normalize(proto(states[1]))))
    assert step.max() > 1e-5  # learning from update 2 on


def test_the_loss_has_the_prototype_terms_and_no_reconstruction(updates):
    _, _, _, metrics = updates
    for m in metrics:
        for name in ("swav_loss", "temp_loss", "norm_loss", "reward_loss", "kl_loss"):
            assert np.isfinite(m[f"wm/{name}"]), name
        assert "wm/image_loss" not in m and "wm/image_mse" not in m
        total = sum(m[f"wm/{k}"] for k in ("swav_loss", "temp_loss", "norm_loss",
                                           "reward_loss", "kl_loss", "gate_loss")
                    if f"wm/{k}" in m)
        np.testing.assert_allclose(m["wm/loss"], total, rtol=1e-5)


def test_the_world_model_trains_on_two_augmented_views(updates):
    agent, batch, states, _ = updates
    wm = agent.world_model
    params, views = wm.representation.training_views(states[0].params["wm"], batch,
                                                     jax.random.PRNGKey(1))
    assert views["image"].shape == (2 * BATCH, LENGTH, 64, 64, 3)
    np.testing.assert_array_equal(views["reward"], np.concatenate([batch["reward"]] * 2))
    assert not np.allclose(views["image"][:BATCH], views["image"][BATCH:])
    norms = np.linalg.norm(params["proto"]["prototypes"], axis=-1)
    np.testing.assert_allclose(norms, 1.0, rtol=1e-6)


def test_the_loss_without_targets_is_a_clear_error(updates):
    agent, batch, states, _ = updates
    with pytest.raises(ValueError, match="EMA target networks"):
        agent.world_model.loss(states[0].params["wm"], batch, jax.random.PRNGKey(0))


def test_the_open_loop_test_predicts_rewards_only(updates):
    """No decoder: ``obs_mse`` is NaN (null in open_loop.jsonl), ``reward_mse`` is measured,
    and there is no open-loop video; decoding states is a clear error."""
    agent, batch, states, _ = updates
    wm_params = states[-1].params["wm"]
    errors = open_loop_errors(agent.config, wm_params, batch, jax.random.PRNGKey(0), 2, 2)
    assert np.isnan(errors["obs_mse"]).all() and np.isfinite(errors["reward_mse"]).all()
    episode = {k: v[0] for k, v in batch.items()}
    assert open_loop_video(agent.config, wm_params, episode, jax.random.PRNGKey(0)) is None
    feat = jnp.zeros((agent.world_model.dynamics.feat_dim,))
    with pytest.raises(ValueError, match="has no decoder"):
        agent.world_model.representation.decode(wm_params, feat)


def test_acting_needs_no_targets(updates):
    agent, batch, states, _ = updates
    obs = {"image": batch["image"][:, 0], "is_first": np.ones(BATCH, bool)}
    params = {k: v for k, v in agent.acting_params(states[-1]).items() if k != "wm_targets"}
    _, action = agent.policy_step(params, agent.initial_carry(BATCH), obs, jax.random.PRNGKey(0))
    assert action.shape == (BATCH, ACTIONS) and np.isfinite(action).all()


def test_gate_statistics_work_on_vsgpro():
    agent, batch, states, _ = _updates("vsgpro")
    summary = agent.gate_summary(states[-1], batch)
    assert 0.0 < summary["gates/open"] < 1.0 and np.isfinite(summary["gates/kl"])


# --- the presets table of docs/dreamerpro.md ---------------------------------------------------

PAGE = Path(__file__).resolve().parents[3] / "docs" / "dreamerpro.md"
TABLE_HEADER = "| key | dreamerpro | vsgpro | source (configs.yaml) |"


def page_table() -> dict:
    """{key: {model: value}} from the page's presets table."""
    return {key.strip("`"): {"dreamerpro": cell_value(pro), "vsgpro": cell_value(vsgpro)}
            for key, pro, vsgpro, _source in table_rows(PAGE.read_text(), TABLE_HEADER)}


def test_the_pages_presets_table_matches_make_config():
    table = page_table()
    wrong = [f"{key} {model}: page {want!r}, make_config {got!r}"
             for key, models in table.items() for model, want in models.items()
             for got in [config_value(make_config(TASK, model, "paper"), key)]
             if got != want or type(got) is not type(want)]
    assert not wrong, "\n".join(wrong)


def test_the_pages_table_names_every_key_that_differs_from_dreamerv2():
    base = to_dict(make_config(TASK, "dreamerv2", "paper"))
    named = set(page_table())
    for model in prototype_models():
        data = to_dict(make_config(TASK, model, "paper"))
        differing = {f"{section}.{key}" for section, values in data.items()
                     if isinstance(values, dict) for key, value in values.items()
                     if section == "proto" or base[section].get(key) != value}
        assert differing <= named, sorted(differing - named)


# --- the tanh-normal actor (DreamerPro's `actor.dist: tanh_normal`) ------------------------------

def _tanh_normal(seed: int = 0, shape=(5, 3)):
    from vsgjax.agents.dreamer.behaviour import TanhNormalActions

    rng = np.random.default_rng(seed)
    mean = jnp.asarray(rng.normal(size=shape), jnp.float32)
    std = jnp.asarray(rng.uniform(0.2, 1.0, shape), jnp.float32)
    return TanhNormalActions(mean, std, jax.random.PRNGKey(seed))


def test_tanh_normal_log_prob_is_tfps_tanh_transformed_normal():
    """dists.py ``TanhBijector`` + nets.py ``DistLayer`` (tanh_normal): the density of
    tanh(u), u ~ N(mean, std), summed over action dimensions."""
    from tensorflow_probability.substrates import jax as tfp

    dist = _tanh_normal()
    action = dist.sample(jax.random.PRNGKey(3))
    reference = tfp.distributions.TransformedDistribution(
        tfp.distributions.Normal(dist.mean, dist.std), tfp.bijectors.Tanh())
    np.testing.assert_allclose(dist.log_prob(action), reference.log_prob(action).sum(-1),
                               rtol=1e-4, atol=1e-4)
    assert np.all(np.abs(action) < 1.0)


def test_tanh_normal_entropy_and_mode_are_the_releases_sample_estimates():
    """dists.py ``SampleDist``: entropy = -mean log p over 100 samples; mode = the most likely
    of 100 samples (drawn with the distribution's key)."""
    dist = _tanh_normal()
    u = dist.mean + dist.std * jax.random.normal(dist.key, (100, *dist.mean.shape))
    log_p = np.stack([np.asarray(dist.log_prob(np.tanh(np.asarray(x)))) for x in u])
    np.testing.assert_allclose(dist.entropy(), -log_p.mean(0), rtol=1e-3, atol=1e-3)
    best = log_p.argmax(0)
    np.testing.assert_allclose(dist.mode(), np.tanh(np.asarray(u))[best, np.arange(5)],
                               rtol=1e-6)
    assert float(jnp.abs(dist.mode() - jnp.tanh(dist.mean)).max()) < 1.0


def test_tanh_normal_entropy_has_a_gradient_through_its_samples():
    from vsgjax.agents.dreamer.behaviour import TanhNormalActions

    key = jax.random.PRNGKey(0)
    grad = jax.grad(lambda s: TanhNormalActions(jnp.zeros(2), s, key).entropy().sum())
    # near 0 tanh is almost linear: a wider pre-tanh Normal has more entropy (at std 0.3)
    assert np.all(np.asarray(grad(jnp.full(2, 0.3))) > 0)


def test_the_prototype_models_act_with_the_tanh_normal_and_the_others_do_not():
    """DreamerPro's ``defaults``: ``actor: {dist: tanh_normal, min_std: 0.1}``; mean
    5·tanh(m/5), std softplus(s) + 0.1 from the actor's two outputs."""
    from vsgjax.agents.dreamer.behaviour import Behaviour, TanhNormalActions, TruncNormalActions

    for model, kind in (("dreamerpro", TanhNormalActions), ("vsgpro", TanhNormalActions),
                        ("dreamerv2", TruncNormalActions)):
        config = make_config(TASK, model, "debug")
        behaviour = Behaviour.from_config(config, ACTIONS, False)
        params = behaviour.init(jax.random.PRNGKey(0), 8)["actor"]
        feat = jnp.ones(8)
        policy = behaviour.policy(params, feat, jax.random.PRNGKey(1))
        assert isinstance(policy, kind), model
    out = behaviour.actor_net.apply({"params": params}, feat)
    config = make_config(TASK, "dreamerpro", "debug")
    policy = Behaviour.from_config(config, ACTIONS, False).policy(params, feat,
                                                                  jax.random.PRNGKey(1))
    np.testing.assert_allclose(policy.mean, 5 * np.tanh(np.asarray(out[:ACTIONS]) / 5), rtol=1e-6)
    np.testing.assert_allclose(policy.std, np.logaddexp(0, np.asarray(out[ACTIONS:])) + 0.1,
                               rtol=1e-5)
