"""Gate statistics (:mod:`vsgjax.agents.dreamer.gate_statistics`) on the real VSG and SVSG
world models.

The sparsity loss alpha*KL(g || Bern(kappa)) must move the gates toward kappa within a bounded
number of world-model updates on fixed episodes. With ``VSGJAX_BREAK_GATE_LOSS=1`` the gate
loss is replaced by zero (the ``gate_loss_on`` fixture), and the tests that use it must then
FAIL: that shows they measure the sparsity loss.
"""

from __future__ import annotations

import os
import re

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vsgjax
from tests.support.registry_names import models
from vsgjax.agents.dreamer import gates
from vsgjax.agents.dreamer.gate_statistics import (
    GateStatistics,
    closed_run_lengths,
    gate_statistics,
)
from vsgjax.agents.dreamer.world_model import WorldModel
from vsgjax.config import make_config
from vsgjax.registry.agents import gated_models
from vsgjax.registry.tasks import VECTOR

BREAK_GATE_LOSS = os.environ.get("VSGJAX_BREAK_GATE_LOSS") == "1"
OBS = {"vector": (8,)}  # the dynamics and gates are those of any task; a vector keeps it fast
UPDATES = 80


def fixed_batch(batch: int = 4, length: int = 16, seed: int = 0) -> dict:
    """A fixed [B, T] batch of vector episodes, one episode start mid-sequence."""
    rng = np.random.default_rng(seed)
    is_first = np.zeros((batch, length), bool)
    is_first[:, 0] = is_first[:, length // 2] = True
    return {
        "vector": rng.normal(size=(batch, length, 8)).astype(np.float32),
        "action": rng.uniform(-1, 1, (batch, length, 2)).astype(np.float32),
        "reward": rng.normal(size=(batch, length)).astype(np.float32),
        "is_first": is_first,
        "is_terminal": np.zeros((batch, length), bool),
    }


def config(model: str = "vsg", alpha: float = 0.1, kappa: float = 0.3):
    return make_config("bbs_basic", model, "debug", [
        f"wm.gate_alpha={alpha}", f"wm.gate_kappa={kappa}", "wm.gate_free=0", "wm.lr=1e-3"])


# --- the sparsity loss moves the gates ------------------------------------------------------

@pytest.fixture(scope="module")
def gate_loss_on():
    """Whether the gate loss reaches the gradient (``VSGJAX_BREAK_GATE_LOSS=1``: zero)."""
    with pytest.MonkeyPatch.context() as patch:
        if BREAK_GATE_LOSS:
            patch.setattr(gates, "sparsity_loss", lambda logit, kappa, alpha, free:
                          jnp.zeros((), jnp.float32))
            jax.clear_caches()  # no train_step compiled with the real loss
        yield not BREAK_GATE_LOSS
    if BREAK_GATE_LOSS:
        jax.clear_caches()


@pytest.fixture(scope="module")
def trained(gate_loss_on):
    """``{(alpha, kappa): (stats before, after UPDATES updates)}`` of VSG; same init and keys."""
    batch, out = fixed_batch(), {}
    for alpha, kappa in [(1.0, 0.1), (0.0, 0.1), (1.0, 0.5)]:
        cfg = config("vsg", alpha, kappa)
        state = vsgjax.init(cfg, jax.random.PRNGKey(0), obs_shape=OBS, action_dim=2)
        before = gate_statistics(state.params, batch, config=cfg)
        for i in range(UPDATES):
            state, _, _ = vsgjax.world_model_step(cfg, state, batch, jax.random.PRNGKey(i))
        out[alpha, kappa] = before, gate_statistics(state.params, batch, config=cfg)
    return out


def _numbers(stats: GateStatistics) -> dict:
    summary = stats.summary()
    return {name: round(summary[f"gates/{name}"], 4) for name in ("open", "prob_post", "kl")}


@pytest.mark.slow
def test_sparsity_loss_moves_the_gate_probability_toward_kappa(trained):
    kappa = 0.1
    start, on = trained[1.0, kappa]
    _, off = trained[0.0, kappa]
    print(f"\nkappa={kappa}, {UPDATES} updates: start {_numbers(start)}; alpha=1 "
          f"{_numbers(on)}; alpha=0 {_numbers(off)}")
    distance = {name: abs(float(s.post_prob.mean()) - kappa)
                for name, s in (("start", start), ("on", on), ("off", off))}
    assert distance["on"] < 0.5 * distance["start"], distance
    assert float(on.kl) < 0.5 * float(start.kl)
    assert distance["off"] > 0.8 * distance["start"], distance
    assert float(off.kl) > 0.8 * float(start.kl)


@pytest.mark.slow
def test_smaller_kappa_gives_a_smaller_open_fraction(trained):
    _, low = trained[1.0, 0.1]
    _, high = trained[1.0, 0.5]
    low, high = float(low.gate.mean()), float(high.gate.mean())
    print(f"\nalpha=1, {UPDATES} updates: open fraction kappa=0.1 {low:.4f}, kappa=0.5 "
          f"{high:.4f}")
    assert low + 0.15 < high


# --- gates, closed units, masked KL (one forward pass) --------------------------------------

@pytest.fixture(scope="module", params=models(gated=True, observes=VECTOR))
def observed(request):
    """``(model, params, batch, stats, posts, priors)`` of a fresh debug world model."""
    cfg = config(request.param)
    params = vsgjax.init(cfg, jax.random.PRNGKey(0), obs_shape=OBS, action_dim=2).params
    batch, key = fixed_batch(), jax.random.PRNGKey(3)
    posts, priors = vsgjax.observe(cfg, params, batch, key)
    model = WorldModel(cfg, OBS, 2)
    return model, params, batch, gate_statistics(params, batch, key, config=cfg), posts, priors


def test_statistics_are_those_of_the_posterior_pass(observed):
    model, _, batch, stats, posts, _ = observed
    np.testing.assert_array_equal(stats.gate, posts.gate)
    np.testing.assert_array_equal(stats.post_prob, jax.nn.sigmoid(posts.gate_logit))
    np.testing.assert_allclose(stats.kl, gates.mean_gate_kl(posts.gate_logit, stats.kappa),
                               rtol=1e-6)
    units = posts.gate.shape[-1]
    assert stats.closed_runs.shape == (batch["is_first"].shape[1],)
    # every closed step belongs to exactly one run
    lengths = np.arange(1, stats.closed_runs.shape[0] + 1)
    assert int((lengths * stats.closed_runs).sum()) == int((stats.gate == 0).sum())
    assert stats.never_open.shape == stats.always_open.shape == (batch["action"].shape[0],)
    assert stats.open_per_unit.shape == (units,)
    summary = stats.summary()
    assert 0.0 < summary["gates/open"] < 1.0 and 0.0 < summary["gates/prob_prior"] < 1.0
    assert ("gates/stoch_updated" in summary) == (model.config.agent == "svsg")


def test_sampled_gates_are_exactly_0_or_1_with_a_straight_through_gradient(observed):
    model, params, batch, stats, _, _ = observed
    for sample in (stats.gate, stats.prior_gate):
        assert bool(jnp.all((sample == 0.0) | (sample == 1.0)))
        assert 0 < int(sample.sum()) < sample.size
    weights = jax.random.normal(jax.random.PRNGKey(5), stats.gate.shape[1:])
    seq = jax.tree.map(lambda x: jnp.asarray(x[0]), batch)

    def weighted_gates(cell_params):
        wm = dict(params, dynamics=dict(params["dynamics"], cell=cell_params))
        posts, _ = model.observe(wm, seq, jax.random.PRNGKey(7))
        return (posts.gate * weights).sum()

    grad = jax.grad(weighted_gates)(params["dynamics"]["cell"])["dense"]["kernel"]
    units = stats.gate.shape[-1]
    update_part = grad[:, 2 * units:]  # the update gate's pre-activations
    assert bool(jnp.all(jnp.isfinite(grad))) and float(jnp.abs(update_part).max()) > 0.0


def test_a_closed_unit_keeps_its_value_exactly(observed):
    model, _, batch, stats, posts, _ = observed
    value = posts.deter if model.config.agent == "vsg" else posts.stoch
    closed = (stats.gate[:, 1:] == 0) & ~batch["is_first"][:, 1:, None]
    opened = (stats.gate[:, 1:] == 1) & ~batch["is_first"][:, 1:, None]
    same = value[:, 1:] == value[:, :-1]
    assert int(closed.sum()) > 0 and bool(jnp.all(same[closed]))
    assert float(same[opened].mean()) < 0.01  # open units take a new value


@pytest.mark.parametrize("observed", ["svsg"], indirect=True)
def test_svsg_closed_dimensions_add_exactly_zero_to_the_masked_kl(observed):
    model, params, batch, stats, posts, priors = observed
    seq = jax.tree.map(lambda x: jnp.asarray(x[0]), batch)
    seq_key = jax.random.split(jax.random.PRNGKey(3), batch["action"].shape[0])[0]
    terms, _ = model.sequence_terms(params, seq, seq_key)  # the key vsgjax.observe gave seq 0
    per_dim = jax.vmap(model.dynamics.kl)(jax.tree.map(lambda x: x[0], posts),
                                          jax.tree.map(lambda x: x[0], priors))  # [T, D]
    gate = stats.gate[0]
    masked = per_dim * gate
    assert float(per_dim[gate == 0].max()) > 0.0  # closed dims do have a KL to hide
    assert bool(jnp.all(masked[gate == 0] == 0.0))
    open_sum = jnp.where(gate == 1, per_dim, 0.0).sum(-1)
    np.testing.assert_allclose(terms["kl_rep"], open_sum, rtol=1e-5)


def test_closed_run_lengths_on_hand_made_gates():
    gate = jnp.array([[0, 0, 1, 0, 0, 0, 1, 1]], jnp.float32)[..., None]
    first = jnp.array([[1, 0, 0, 0, 1, 0, 0, 0]], bool)
    # runs: steps 0-1 (2), step 3 (1, cut by the episode start at 4), steps 4-5 (2)
    np.testing.assert_array_equal(closed_run_lengths(gate, first), [1, 2, 0, 0, 0, 0, 0, 0])
    always_closed = jnp.zeros((2, 5, 3))
    np.testing.assert_array_equal(closed_run_lengths(always_closed, jnp.zeros((2, 5), bool)),
                                  [0, 0, 0, 0, 6])


# --- bad input ------------------------------------------------------------------------------

@pytest.mark.parametrize("name", models(gated=False))
def test_models_without_gates_are_refused_by_name(name):
    gated = re.escape(", ".join(gated_models()))
    with pytest.raises(ValueError, match=f"model '{name}' has no gates.*{gated}"):
        gate_statistics({}, fixed_batch(), config=make_config("bbs_basic", name, "debug"))


def test_mismatched_shapes_name_the_expected_ones(observed):
    model, params, batch, _, _, _ = observed
    cfg = model.config
    with pytest.raises(ValueError, match=r"'action' has shape \(4, 16, 3\).*\[4, 16, 2\]"):
        gate_statistics(params, dict(batch, action=np.zeros((4, 16, 3))), config=cfg)
    with pytest.raises(ValueError, match=r"'is_first' has shape \(16,\); expected \[B, T\]"):
        gate_statistics(params, jax.tree.map(lambda x: x[0], batch), config=cfg)
    with pytest.raises(ValueError, match=r"leading dims \(4, 15\); expected \[B, T\] = \[4, 16\]"):
        gate_statistics(params, dict(batch, vector=batch["vector"][:, 1:]), config=cfg)
    with pytest.raises(ValueError, match="lack key 'vector'"):
        gate_statistics(params, {k: v for k, v in batch.items() if k != "vector"}, config=cfg)
    with pytest.raises(TypeError, match="config="):
        gate_statistics(params, batch)
