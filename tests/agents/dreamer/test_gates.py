"""Gate sparsity loss, gate statistics, and a short training run with and without the loss."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from vsgjax.agents.dreamer.cells import cell_init, dense, dense_init, sparse_gru_cell
from vsgjax.agents.dreamer.gates import bernoulli_kl, gate_metrics, mean_gate_kl, sparsity_loss


def _closed_form_kl(p, kappa):
    p = np.asarray(p, np.float64)
    return p * np.log(p / kappa) + (1 - p) * np.log((1 - p) / (1 - kappa))


def test_bernoulli_kl_matches_closed_form():
    logits = jnp.array([-5.0, -1.0, -0.2, 0.0, 0.7, 3.0])
    p = 1 / (1 + np.exp(-np.asarray(logits, np.float64)))
    np.testing.assert_allclose(bernoulli_kl(logits, 0.3), _closed_form_kl(p, 0.3), rtol=1e-5)
    # zero exactly at p = kappa
    np.testing.assert_allclose(bernoulli_kl(jnp.log(jnp.array([0.4 / 0.6])), 0.4), 0.0, atol=1e-6)


def test_sparsity_loss_equals_closed_form_with_free_nats_clamp():
    logits = jax.random.normal(jax.random.PRNGKey(0), (2, 3, 5)) * 2
    p = 1 / (1 + np.exp(-np.asarray(logits, np.float64)))
    mean_kl = _closed_form_kl(p, 0.3).sum(-1).mean()
    assert mean_kl > 0.5
    np.testing.assert_allclose(mean_gate_kl(logits, 0.3), mean_kl, rtol=1e-5)
    np.testing.assert_allclose(sparsity_loss(logits, 0.3, 0.1, 0.1), 0.1 * mean_kl, rtol=1e-5)
    # below the free nats the loss is the constant alpha * free and sends no gradient
    clamped = sparsity_loss(logits, 0.3, 0.1, free=mean_kl + 1.0)
    np.testing.assert_allclose(clamped, 0.1 * (mean_kl + 1.0), rtol=1e-5)
    grad = jax.grad(lambda lg: sparsity_loss(lg, 0.3, 0.1, free=mean_kl + 1.0))(logits)
    assert np.all(np.asarray(grad) == 0)
    grad = jax.grad(lambda lg: sparsity_loss(lg, 0.3, 0.1, free=0.0))(logits)
    # d/dlogit of alpha * mean_{B,T} KL = alpha / (B*T) * p(1-p) * (logit - logit(kappa))
    expected = 0.1 / 6 * p * (1 - p) * (np.asarray(logits) - np.log(0.3 / 0.7))
    np.testing.assert_allclose(grad, expected, rtol=1e-4, atol=1e-8)


@pytest.mark.parametrize("logit", [1e4, -1e4])
def test_sparsity_loss_is_finite_for_saturated_logits(logit):
    logits = jnp.full((2, 4), logit)
    value, grad = jax.value_and_grad(lambda lg: sparsity_loss(lg, 0.3, 0.1, 0.0))(logits)
    kappa = 0.3 if logit > 0 else 0.7  # KL(Bern(1)||Bern(.3)) = -log .3, KL(Bern(0)||.) = -log .7
    np.testing.assert_allclose(value, 0.1 * 4 * -np.log(kappa), rtol=1e-5)
    assert np.isfinite(np.asarray(grad)).all()


def test_kappa_outside_unit_interval_is_an_error():
    with pytest.raises(ValueError, match="kappa.*got 1.5"):
        bernoulli_kl(jnp.zeros(3), 1.5)


def test_gate_metrics_on_hand_made_gates():
    # B=2, T=3, D=4
    gate = jnp.array([
        [[1, 0, 0, 0], [1, 1, 0, 0], [1, 1, 1, 0]],
        [[0, 0, 0, 0], [0, 0, 0, 1], [1, 1, 1, 1]],
    ], jnp.float32)
    prob = jnp.full(gate.shape, 0.25).at[1].set(0.75)
    stats = gate_metrics(gate, prob)
    per_step = np.array([1, 2, 3, 0, 1, 4])
    per_unit = np.array([3, 2, 1, 0, 1, 1, 1, 2])
    np.testing.assert_allclose(stats["gate_units_per_step_mean"], per_step.mean())
    np.testing.assert_allclose(stats["gate_units_per_step_std"], per_step.std(), rtol=1e-6)
    np.testing.assert_allclose(stats["gate_updates_per_unit_mean"], per_unit.mean())
    np.testing.assert_allclose(stats["gate_updates_per_unit_std"], per_unit.std(), rtol=1e-6)
    np.testing.assert_allclose(stats["gate_open_fraction"], 11 / 24)
    np.testing.assert_allclose(stats["gate_prob_mean"], 0.5)
    # a single [T, D] sequence gives the statistics of its batch slice
    single = gate_metrics(gate[0], prob[0])
    np.testing.assert_allclose(single["gate_units_per_step_mean"], 2.0)
    np.testing.assert_allclose(single["gate_updates_per_unit_std"], np.std([3, 2, 1, 0]), rtol=1e-6)


def test_gate_metrics_rejects_bad_shapes():
    with pytest.raises(ValueError, match=r"\[T, D\] or \[B, T, D\].*\(4,\)"):
        gate_metrics(jnp.zeros(4), jnp.zeros(4))


# --- a short training run -----------------------------------------------------------------------
# Synthetic task: reconstruct the current input x_t (4 dims) from the cell state h_t (8 units).
# Copying the input needs the gates open at every step, so the reconstruction alone pushes the
# gate probability up (towards 1); the sparsity loss pulls it towards kappa = 0.1.

IN, D, T, BATCH, STEPS, KAPPA = 4, 8, 8, 16, 150, 0.1


def _init(key):
    cell_key, out_key = jax.random.split(key)
    return {"cell": cell_init(cell_key, IN, D, norm=False), "readout": dense_init(out_key, D, IN)}


def _sequence_losses(params, inputs, key):
    """Per-example reconstruction error and gate logits [T, D] of one sequence."""

    def step(h, xs):
        x, step_key = xs
        out = sparse_gru_cell(params["cell"], h, x, step_key)
        return out.state, (out.state, out.gate_logit)

    keys = jax.random.split(key, inputs.shape[0])
    _, (states, logits) = jax.lax.scan(step, jnp.zeros(D), (inputs, keys))
    return jnp.square(dense(params["readout"], states) - inputs).mean(), logits


def _batch(params, key):
    data_key, gate_key = jax.random.split(key)
    inputs = jax.random.normal(data_key, (BATCH, T, IN))
    recon, logits = jax.vmap(_sequence_losses, (None, 0, 0))(
        params, inputs, jax.random.split(gate_key, BATCH)
    )
    return recon.mean(), logits


@jax.jit
def _train(alpha, key):
    """Adam on reconstruction + alpha * sparsity loss; mean gate probability before and after."""
    optimizer = optax.adam(1e-2)
    params = _init(jax.random.PRNGKey(0))
    eval_key, train_key = jax.random.split(key)

    def loss(params, key):
        recon, logits = _batch(params, key)
        return recon + sparsity_loss(logits, KAPPA, alpha, free=0.0)

    def update(carry, step_key):
        params, opt_state = carry
        grads = jax.grad(loss)(params, step_key)
        updates, opt_state = optimizer.update(grads, opt_state)
        return (optax.apply_updates(params, updates), opt_state), None

    mean_prob = lambda params: jax.nn.sigmoid(_batch(params, eval_key)[1]).mean()
    before = mean_prob(params)
    (params, _), _ = jax.lax.scan(
        update, (params, optimizer.init(params)), jax.random.split(train_key, STEPS)
    )
    return before, mean_prob(params), _batch(params, eval_key)[0]


def test_sparsity_loss_moves_gate_probability_towards_kappa():
    key = jax.random.PRNGKey(1)
    start, without_loss, recon_without = (float(v) for v in _train(0.0, key))
    same_start, with_loss, recon_with = (float(v) for v in _train(1.0, key))
    _, with_paper_alpha, _ = (float(v) for v in _train(0.1, key))
    assert start == same_start
    assert without_loss > start + 0.1  # the task alone opens the gates
    assert with_loss < start  # the sparsity loss pulls the gates towards kappa
    assert abs(with_loss - KAPPA) < abs(without_loss - KAPPA) - 0.3
    assert with_loss < with_paper_alpha < without_loss - 0.1  # stronger loss, sparser gates
    assert recon_without < recon_with  # sparser gates cost reconstruction on this task
