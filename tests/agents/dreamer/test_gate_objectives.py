"""The gate objectives (``wm.gate_objective``, vsgjax/agents/dreamer/gate_objectives.py): each
loss against its equation on hand-computed gates, closing is free under the one-sided ones,
GateL0RD's ReTanh gate, the config's refusals, and a world-model update with each objective
for VSG, SVSG and VSGPro."""

from __future__ import annotations

import math
from dataclasses import replace

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vsgjax
from tests.support.registry_names import models
from vsgjax import train
from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.agents.dreamer.cells import (
    RETANH,
    GateCell,
    cell_init,
    open_probability,
    retanh_gate,
    sparse_gru_cell,
)
from vsgjax.agents.dreamer.gate_objectives import LOSS_NAMES, gate_cell, gate_loss, rate_kl
from vsgjax.agents.dreamer.settings import GATE_OBJECTIVES, WorldModelConfig
from vsgjax.config import ConfigError, make_config
from vsgjax.registry.agents import gated_models

LOGITS = np.array([[[-2.0, 0.5], [1.0, -0.3]]], np.float32)  # [B=1, T=2, D=2]
P = 1 / (1 + np.exp(-LOGITS.astype(np.float64)))


def _kl(p, kappa):
    return p * np.log(p / kappa) + (1 - p) * np.log((1 - p) / (1 - kappa))


def _wm(objective: str, **values) -> WorldModelConfig:
    return replace(WorldModelConfig(), gate_objective=objective, **values)


def _loss(objective: str, gate=None, logits=LOGITS, **values) -> tuple[float, dict]:
    gate = jnp.zeros_like(logits) if gate is None else gate
    losses, metrics = gate_loss(_wm(objective, **values), gate, jnp.asarray(logits))
    (name, value), = losses.items()
    assert name == LOSS_NAMES[objective][0]
    return float(value), {key: float(v) for key, v in metrics.items()}


# --- each loss is its equation --------------------------------------------------------------

def test_release_is_the_kl_of_each_step_summed_over_units():
    value, metrics = _loss("release", gate_alpha=0.1, gate_kappa=0.3, gate_free=0.0)
    kl = _kl(P, 0.3).sum(-1).mean()
    np.testing.assert_allclose([value, metrics["gate_kl"]], [0.1 * kl, kl], rtol=1e-5)


def test_rate_is_lambda_times_the_mean_probability():
    value, metrics = _loss("rate", gate_lambda=0.5)
    np.testing.assert_allclose([value, metrics["gate_rate"]], [0.5 * P.mean(), P.mean()],
                               rtol=1e-6)
    assert "gate_kl" in metrics  # the release's KL, for comparison


def test_rate_kl_is_the_kl_of_each_units_rate_to_kappa():
    value, metrics = _loss("rate_kl", gate_alpha=0.1, gate_kappa=0.3, gate_free=0.0)
    rates = P.mean((0, 1))  # [D]
    kl = _kl(rates, 0.3).sum()
    np.testing.assert_allclose([value, metrics["gate_rate_kl"]], [0.1 * kl, kl], rtol=1e-5)
    clamped, _ = _loss("rate_kl", gate_alpha=0.1, gate_kappa=0.3, gate_free=kl + 1)
    np.testing.assert_allclose(clamped, 0.1 * (kl + 1), rtol=1e-5)


def test_gatel0rd_is_lambda_times_the_fraction_of_open_gates():
    theta, _ = retanh_gate(jnp.asarray(LOGITS), jax.random.PRNGKey(0), 0.1, "threshold")
    np.testing.assert_array_equal(theta, LOGITS > 0)
    value, metrics = _loss("gatel0rd", gate=theta, gate_lambda=2.0)
    np.testing.assert_allclose([value, metrics["gate_l0"]], [2.0 * 0.5, 0.5])
    assert "gate_kl" not in metrics  # the ReTanh gate has no Bernoulli logit


# --- closing is free --------------------------------------------------------------------------

def _l0_penalty(update, lam=1.0):
    theta, _ = retanh_gate(update, jax.random.PRNGKey(0), 0.1, "threshold")
    return gate_loss(_wm("gatel0rd", gate_lambda=lam), theta, update)[0]["gate_l0_loss"]


def test_gatel0rd_charges_nothing_for_a_closed_gate_and_pushes_open_ones_closed():
    closed = jnp.array([-3.0, -0.5, -0.01])
    value, grad = jax.value_and_grad(_l0_penalty)(closed)
    assert float(value) == 0.0 and np.all(np.asarray(grad) == 0.0)
    opened = jnp.array([0.2, 1.0, -1.0])
    grad = np.asarray(jax.grad(_l0_penalty)(opened))
    # identity through Θ, then dΛ/du = 1 - tanh²(u) where open, 0 where closed; / N
    np.testing.assert_allclose(grad, [(1 - np.tanh(0.2) ** 2) / 3, (1 - np.tanh(1.0) ** 2) / 3,
                                      0.0], rtol=1e-5)


def test_rate_only_ever_pushes_toward_closing_and_vanishes_when_closed():
    grad = jax.grad(lambda lg: _rate(lg))(jnp.asarray(LOGITS))
    assert np.all(np.asarray(grad) > 0)  # gradient descent lowers every logit
    assert _rate(jnp.full((1, 2, 2), -30.0)) < 1e-12


def _rate(logits):
    return gate_loss(_wm("rate", gate_lambda=1.0), jnp.zeros_like(logits), logits)[0][
        "gate_rate_loss"]


def test_rate_kl_lets_a_unit_hold_for_free_where_the_release_charges_every_step():
    """A unit shut for 7 steps and open for 3 (rate 0.3 = kappa) costs nothing under rate_kl;
    the release charges it about 0.5 nats a step."""
    p = np.array([1e-6] * 7 + [1 - 1e-6] * 3)
    logits = jnp.asarray(np.log(p / (1 - p)), jnp.float32)[None, :, None]  # [1, 10, 1]
    held, grad = jax.value_and_grad(lambda lg: rate_kl(lg, 0.3))(logits)
    assert float(held) < 1e-6 and np.abs(np.asarray(grad)).max() < 1e-6
    release, _ = _loss("release", logits=logits, gate_alpha=1.0, gate_kappa=0.3, gate_free=0.0)
    assert release > 0.5


# --- GateL0RD's ReTanh gate in the cell -------------------------------------------------------

def test_retanh_gate_noise_only_when_sampling_and_its_open_probability():
    update = jnp.full((20000,), 0.05)
    theta, weight = retanh_gate(update, jax.random.PRNGKey(1), 0.1, "sample")
    measured = float(theta.mean())
    assert 0.5 < measured < 1.0  # u > 0, but the noise closes some gates
    np.testing.assert_allclose(measured, float(open_probability(GateCell(RETANH, 0.1),
                                                                jnp.array(0.05))), atol=0.01)
    np.testing.assert_allclose(measured, 0.5 * (1 + math.erf(0.5 / math.sqrt(2))), atol=0.01)
    theta, weight = retanh_gate(update, jax.random.PRNGKey(1), 0.1, "threshold")
    np.testing.assert_allclose(weight, np.tanh(0.05), rtol=1e-6)
    assert float(theta.min()) == 1.0


def test_a_closed_retanh_gate_copies_the_state_bit_for_bit_and_open_ones_mix():
    key = jax.random.PRNGKey(0)
    params = cell_init(key, 3, 4, norm=False)
    h_prev = jnp.array([1e-40, -0.7, 0.3, 2.0])  # a subnormal too
    x = jax.random.normal(jax.random.PRNGKey(1), (3,))
    out = sparse_gru_cell(params, h_prev, x, key, mode="threshold", gate=GateCell(RETANH, 0.1))
    closed = np.asarray(out.weight) == 0
    assert closed.any() and (~closed).any(), "pick inputs with both kinds of gate"
    np.testing.assert_array_equal(np.asarray(out.state)[closed], np.asarray(h_prev)[closed])
    mix = out.weight * out.candidate + (1 - out.weight) * h_prev
    np.testing.assert_allclose(np.asarray(out.state)[~closed], np.asarray(mix)[~closed])
    np.testing.assert_array_equal(out.gate, ~closed)


# --- config ---------------------------------------------------------------------------------

def test_the_objective_picks_the_gate():
    assert gate_cell(_wm("gatel0rd", gate_noise=0.2)) == GateCell(RETANH, 0.2)
    assert {gate_cell(_wm(name)) for name in ("release", "rate", "rate_kl")} == {GateCell()}


@pytest.mark.parametrize("overrides, model, named", [
    (["wm.gate_objective=l0"], "vsg", ["'l0'", *GATE_OBJECTIVES]),
    (["wm.gate_objective=rate"], "dreamerv2", ["rate", "'dreamerv2'", *gated_models()]),
    (["wm.gate_objective=gatel0rd"], "ssm", ["gatel0rd", "'ssm'", *gated_models()]),
    (["wm.gate_objective=gatel0rd", "model.gate_bias=0"], "vsg",
     ["model.gate_bias=0.0", "gatel0rd", "model.gate_bias=-1.0"]),
    (["wm.gate_lambda=-1"], "vsg", ["wm.gate_lambda", "-1.0", ">= 0"]),
    (["wm.gate_noise=-0.1"], "svsg", ["wm.gate_noise", ">= 0"]),
])
def test_bad_gate_settings_are_refused_naming_the_value_and_what_is_valid(overrides, model,
                                                                          named):
    with pytest.raises(ConfigError) as error:
        make_config("bbs_basic", model, "debug", overrides)
    for text in named:
        assert text in str(error.value), (text, str(error.value))


def test_a_refused_objective_writes_nothing(tmp_path, capsys):
    logdir = tmp_path / "run"
    argv = ["--task", "mjx_cartpole_swingup", "--model", "dreamerv2", "--size", "debug",
            "--logdir", str(logdir), "--no-progress", "wm.gate_objective=rate_kl"]
    assert train.main(argv) == 2
    assert "'dreamerv2'" in capsys.readouterr().err and not logdir.exists()


# --- a world-model update with each objective -------------------------------------------------

def _batch(image: bool, batch: int = 2, length: int = 5) -> dict:
    rng = np.random.default_rng(0)
    is_first = np.zeros((batch, length), bool)
    is_first[:, 0] = True
    obs = ({"image": rng.integers(0, 256, (batch, length, 64, 64, 3), dtype=np.uint8)} if image
           else {"vector": rng.normal(size=(batch, length, 6)).astype(np.float32)})
    return {**obs, "action": rng.uniform(-1, 1, (batch, length, 2)).astype(np.float32),
            "reward": rng.normal(size=(batch, length)).astype(np.float32),
            "is_first": is_first, "is_terminal": np.zeros((batch, length), bool)}


def _check_update(objective: str, metrics: dict, prefix: str = "") -> None:
    loss_name, value_name = LOSS_NAMES[objective]
    assert np.isfinite(float(metrics[f"{prefix}loss"]))
    assert np.isfinite(float(metrics[f"{prefix}{loss_name}"]))
    assert float(metrics[f"{prefix}{value_name}"]) >= 0
    others = {name for o, names in LOSS_NAMES.items() if o != objective for name in names[:1]}
    assert not others & set(metrics), "one gate loss per objective"


@pytest.mark.parametrize("model", models(gated=True, prototypes=False))
@pytest.mark.parametrize("objective", GATE_OBJECTIVES)
def test_a_world_model_update_trains_the_gate_with_each_objective(model, objective):
    cfg = make_config("bbs_basic", model, "debug", [f"wm.gate_objective={objective}"])
    state = vsgjax.init(cfg, jax.random.PRNGKey(0), obs_shape={"vector": (6,)}, action_dim=2)
    new, metrics, posts = vsgjax.world_model_step(cfg, state, _batch(False),
                                                  jax.random.PRNGKey(1))
    _check_update(objective, metrics)
    gate = np.asarray(posts.gate)
    assert set(np.unique(gate)) <= {0.0, 1.0}  # Θ or the Bernoulli sample: exactly 0/1
    cell = lambda params: np.asarray(params["dynamics"]["cell"]["dense"]["kernel"])
    assert not np.array_equal(cell(new.params), cell(state.params))


@pytest.mark.slow
@pytest.mark.parametrize("objective", GATE_OBJECTIVES[1:])
def test_vsgpro_trains_with_each_objective(objective):
    cfg = make_config("bbs_basic", "vsgpro", "debug", [
        f"wm.gate_objective={objective}", "proto.prototypes=16", "train.length=5"])
    agent = DreamerAgent(cfg, (64, 64, 3), 2, False)
    _, metrics = agent.train_step(agent.init(jax.random.PRNGKey(0)), _batch(True),
                                  jax.random.PRNGKey(7))
    _check_update(objective, jax.device_get(metrics), prefix="wm/")
