"""Cells: GRU formula, sparse gate sampling, exact copying, straight-through gradients."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vsgjax.agents.dreamer.cells import (
    cell_init,
    dense,
    gated_update,
    gru_cell,
    sparse_gru_cell,
    straight_through_gate,
)

IN, D = 5, 6


def _inputs(seed=0):
    kp, kh, kx = jax.random.split(jax.random.PRNGKey(seed), 3)
    return (
        cell_init(kp, IN, D, norm=False),
        jax.random.normal(kh, (D,)),
        jax.random.normal(kx, (IN,)),
    )


def _reference_parts(params, h, x, gate_bias=-1.0):
    """Candidate and update probability written out with numpy, float64."""
    kernel = np.asarray(params["dense"]["kernel"], np.float64)
    bias = np.asarray(params["dense"]["bias"], np.float64)
    pre = np.concatenate([np.asarray(x), np.asarray(h)]) @ kernel + bias
    r, c, u = np.split(pre, 3)
    sig = lambda v: 1 / (1 + np.exp(-v))
    return np.tanh(sig(r) * c), sig(u + gate_bias), sig(r)


def test_gru_cell_matches_reference_formula():
    params, h, x = _inputs()
    cand, p, _ = _reference_parts(params, h, x)
    expected = p * cand + (1 - p) * np.asarray(h)
    np.testing.assert_allclose(gru_cell(params, h, x), expected, rtol=1e-5, atol=1e-6)


def test_layer_norm_option_changes_output():
    _, h, x = _inputs()
    key = jax.random.PRNGKey(3)
    plain, normed = cell_init(key, IN, D, norm=False), cell_init(key, IN, D, norm=True)
    assert set(normed) == {"dense", "norm"}
    out_plain, out_norm = gru_cell(plain, h, x), gru_cell(normed, h, x)
    assert np.abs(np.asarray(out_plain - out_norm)).max() > 1e-3
    # LayerNorm of all 3D pre-activations: zero mean / unit variance before scale and bias.
    pre = dense(normed["dense"], jnp.concatenate([x, h]))
    normalised = (pre - pre.mean()) / jnp.sqrt(pre.var() + 1e-3)
    r, c, u = jnp.split(normalised, 3)
    expected = jax.nn.sigmoid(u - 1) * jnp.tanh(jax.nn.sigmoid(r) * c)
    expected += (1 - jax.nn.sigmoid(u - 1)) * h
    np.testing.assert_allclose(out_norm, expected, rtol=1e-5, atol=1e-6)


def test_sparse_cell_probability_and_candidate_match_reference():
    params, h, x = _inputs()
    out = sparse_gru_cell(params, h, x, jax.random.PRNGKey(1))
    cand, p, _ = _reference_parts(params, h, x)
    np.testing.assert_allclose(out.candidate, cand, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(jax.nn.sigmoid(out.gate_logit), p, rtol=1e-5, atol=1e-6)
    assert set(np.unique(np.asarray(out.gate))) <= {0.0, 1.0}


def test_open_gate_frequency_matches_probability():
    logits = jnp.array([-6.0, -2.0, -1.0, 0.0, 0.5, 1.5, 4.0])
    n = 20_000
    keys = jax.random.split(jax.random.PRNGKey(0), n)
    gates = jax.jit(jax.vmap(lambda k: straight_through_gate(logits, k)))(keys)
    freq = np.asarray(gates).mean(0)
    p = np.asarray(jax.nn.sigmoid(logits), np.float64)
    bound = 5 * np.sqrt(p * (1 - p) / n) + 1e-4  # 5 binomial standard deviations
    assert np.all(np.abs(freq - p) < bound), (freq, p)


def test_threshold_mode_is_deterministic_and_still_straight_through():
    logits = jnp.array([-0.3, 0.0, 0.2, 3.0])
    g1 = straight_through_gate(logits, jax.random.PRNGKey(0), "threshold")
    g2 = straight_through_gate(logits, jax.random.PRNGKey(1), "threshold")
    np.testing.assert_array_equal(g1, [0, 0, 1, 1])
    np.testing.assert_array_equal(g1, g2)
    grad = jax.grad(lambda logit: straight_through_gate(logit, None, "threshold").sum())(logits)
    p = jax.nn.sigmoid(logits)
    np.testing.assert_allclose(grad, p * (1 - p), rtol=1e-6)


def test_unknown_gate_mode_is_an_error():
    with pytest.raises(ValueError, match="'soft'.*sample, threshold"):
        straight_through_gate(jnp.zeros(2), jax.random.PRNGKey(0), "soft")


def test_closed_gates_copy_state_bit_for_bit():
    params, _, x = _inputs()
    # Awkward values: tiny, huge, negative zero, subnormal-ish, values beyond tanh's range.
    h_prev = jnp.array([1e-30, -3.7e12, -0.0, 1.17e-38, 7.25, -0.3333333])
    run = jax.jit(lambda k: sparse_gru_cell(params, h_prev, x, k))
    closed_seen = open_seen = 0
    for seed in range(20):
        out = run(jax.random.PRNGKey(seed))
        closed = np.asarray(out.gate) == 0
        bits = lambda a: np.asarray(a).view(np.uint32)
        np.testing.assert_array_equal(bits(out.state)[closed], bits(h_prev)[closed])
        np.testing.assert_array_equal(bits(out.state)[~closed], bits(out.candidate)[~closed])
        closed_seen += closed.sum()
        open_seen += (~closed).sum()
    assert closed_seen > 0 and open_seen > 0


def test_straight_through_gradient_equals_analytic():
    """dh/dp = ĉ - h_prev and dh/dĉ = g, checked through the cell's own biases."""
    params, h, x = _inputs()
    key = jax.random.PRNGKey(5)
    out = sparse_gru_cell(params, h, x, key)
    cand, p, sig_r = _reference_parts(params, h, x)
    g = np.asarray(out.gate)

    def state_of_bias(bias):
        new = {"dense": {"kernel": params["dense"]["kernel"], "bias": bias}}
        return sparse_gru_cell(new, h, x, key).state

    jac = np.asarray(jax.jacobian(state_of_bias)(params["dense"]["bias"]))  # [D, 3D]
    d_update = np.diagonal(jac[:, 2 * D:])
    d_candidate = np.diagonal(jac[:, D:2 * D])
    np.testing.assert_allclose(d_update, (cand - np.asarray(h)) * p * (1 - p), rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(d_candidate, g * (1 - cand**2) * sig_r, rtol=1e-4, atol=1e-7)
    # each unit's gate depends only on its own update pre-activation
    off_diagonal = jac[:, 2 * D:] - np.diag(d_update)
    assert np.abs(off_diagonal).max() == 0.0


def test_gated_update_gradients_are_those_of_the_linear_formula():
    gate_logit = jnp.array([-1.0, 2.0])
    new, old = jnp.array([0.5, -0.25]), jnp.array([2.0, 3.0])
    key = jax.random.PRNGKey(0)
    gate = straight_through_gate(gate_logit, key)

    def via_select(new, old, logit):
        return gated_update(straight_through_gate(logit, key), new, old).sum()

    def via_linear(new, old, logit):
        g = straight_through_gate(logit, key)
        return (g * new + (1 - g) * old).sum()

    for a, b in zip(jax.grad(via_select, (0, 1, 2))(new, old, gate_logit),
                    jax.grad(via_linear, (0, 1, 2))(new, old, gate_logit), strict=True):
        np.testing.assert_allclose(a, b, rtol=1e-6)
    np.testing.assert_array_equal(gated_update(gate, new, old), jnp.where(gate > 0, new, old))


@pytest.mark.parametrize("sign", [1.0, -1.0])
def test_saturated_gates_give_no_nan(sign):
    params, h, x = _inputs()
    bias = params["dense"]["bias"].at[2 * D:].set(sign * 1e4)
    params = {"dense": {"kernel": params["dense"]["kernel"], "bias": bias}}

    def loss(params):
        out = sparse_gru_cell(params, h, x, jax.random.PRNGKey(0))
        return out.state.sum() + out.gate.sum() + jax.nn.log_sigmoid(out.gate_logit).sum()

    value, grads = jax.value_and_grad(loss)(params)
    out = sparse_gru_cell(params, h, x, jax.random.PRNGKey(0))
    np.testing.assert_array_equal(out.gate, np.full(D, sign > 0, np.float32))
    assert np.isfinite(value)
    assert all(np.isfinite(np.asarray(g)).all() for g in jax.tree.leaves(grads))
