"""DreamerPro's prototype losses, augmentation and EMA target
(vsgjax.agents.dreamer.representation.prototype_losses).

Every expected value is re-derived here in numpy (float64) from the authors' release
(fdeng18/dreamer-pro, ``DreamerPro/``), cited in each test, or from TensorFlow's
``ImageProjectiveTransform`` kernel that the release's ``tfa.image.translate`` runs; the code
under test is never its own reference. Tiny shapes: the file runs in seconds.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vsgjax.agents.dreamer.representation.prototype_losses import (
    ema_update,
    freeze,
    l2_normalize,
    prototype_losses,
    sinkhorn,
    translate,
    translate_by,
    two_views,
)

HPARAMS = dict(temperature=0.1, sinkhorn_eps=0.05, sinkhorn_iters=3, warm_up=1)


# ---------------------------------------------------------------- numpy re-derivations


def _np_logsumexp(x, axis):
    m = np.max(x, axis=axis, keepdims=True)
    return m + np.log(np.sum(np.exp(x - m), axis=axis, keepdims=True))


def _np_log_softmax(x, axis):
    return x - _np_logsumexp(x, axis)


def _np_sinkhorn(scores, eps, iters):
    """common/nets.py RSSM.sinkhorn, line by line, in float64."""
    scores = np.asarray(scores, np.float64)
    shape, k = scores.shape, scores.shape[0]
    log_q = _np_log_softmax(scores.reshape(-1) / eps, axis=0).reshape(k, -1)
    n = log_q.shape[1]
    for _ in range(iters):
        log_q = log_q - _np_logsumexp(log_q, 1) - np.log(k)
        log_q = log_q - _np_logsumexp(log_q, 0) - np.log(n)
    return np.exp(log_q + np.log(n)).reshape(shape)


def _np_unit(x):
    x = np.asarray(x, np.float64)
    return x / np.sqrt(np.maximum((x**2).sum(-1, keepdims=True), 1e-12))


def _np_proto_loss(protos, obs, feat, ema, temperature, eps, iters, warm_up, swap=True):
    """common/nets.py RSSM.proto_loss in float64 (``swap=False``: each view's logits against
    its own view's targets, the variant the release does NOT compute)."""
    protos = np.asarray(protos, np.float64)
    obs, feat, ema = (np.asarray(a, np.float64) for a in (obs, feat, ema))
    b, t, d = obs.shape
    k = protos.shape[0]

    def scores(z):  # [K, B, T - w]
        return (protos @ z.reshape(b * t, d).T).reshape(k, b, t)[:, :, warm_up:]

    obs_logits = _np_log_softmax(scores(_np_unit(obs)) / temperature, 0)
    feat_logits = _np_log_softmax(scores(_np_unit(feat)) / temperature, 0)
    lp1, lp2 = obs_logits[:, : b // 2], obs_logits[:, b // 2 :]
    ema_scores = scores(ema)
    q1 = _np_sinkhorn(ema_scores[:, : b // 2], eps, iters)
    q2 = _np_sinkhorn(ema_scores[:, b // 2 :], eps, iters)
    q = np.concatenate([q1, q2], 1)
    if swap:
        swav = -0.5 * (q2 * lp1).sum(0).mean() - 0.5 * (q1 * lp2).sum(0).mean()
    else:
        swav = -0.5 * (q1 * lp1).sum(0).mean() - 0.5 * (q2 * lp2).sum(0).mean()
    temp = -(q * feat_logits).sum(0).mean()
    norm = ((np.linalg.norm(obs, axis=-1) - 1) ** 2).mean() + (
        (np.linalg.norm(feat, axis=-1) - 1) ** 2
    ).mean()
    return {"swav": swav, "temp": temp, "norm": norm}


def _inputs(seed=0, k=6, d=4, b0=2, t=4):
    rng = np.random.default_rng(seed)
    protos = _np_unit(rng.normal(size=(k, d))).astype(np.float32)
    obs = (rng.normal(size=(2 * b0, t, d)) * 1.5).astype(np.float32)
    feat = (rng.normal(size=(2 * b0, t, d)) * 0.7).astype(np.float32)
    ema = _np_unit(rng.normal(size=(2 * b0, t, d))).astype(np.float32)
    return protos, obs, feat, ema


def _np_tf_bilinear_nearest(image, dx, dy):
    """TF's ImageProjectiveTransform kernel (tensorflow/core/kernels/image/image_ops.h,
    ProjectiveGenerator) for tfa.image.translate's transform [1, 0, -dx, 0, 1, -dy, 0, 0],
    fill_mode NEAREST (MapCoordinate clamps to [0, len - 1]) and BILINEAR interpolation
    (reads outside the image give the fill value 0, always with weight 0 here)."""
    h, w = image.shape[:2]
    image = np.asarray(image, np.float64)
    out = np.zeros_like(image)

    def read(y, x):
        return image[y, x] if (0 <= y < h and 0 <= x < w) else 0.0

    for oy in range(h):
        for ox in range(w):
            x = min(max(ox - dx, 0.0), w - 1.0)
            y = min(max(oy - dy, 0.0), h - 1.0)
            yf, xf = np.floor(y), np.floor(x)
            yc, xc = yf + 1, xf + 1
            top = (xc - x) * read(int(yf), int(xf)) + (x - xf) * read(int(yf), int(xc))
            bottom = (xc - x) * read(int(yc), int(xf)) + (x - xf) * read(int(yc), int(xc))
            out[oy, ox] = (yc - y) * top + (y - yf) * bottom
    return out


def _ramp_images(b, t, h=16, w=16):
    """Channel 0 = column index x, channel 1 = row index y, same for every frame: bilinear
    interpolation of a linear function is exact, so away from the clamped border
    ``out = x - dx`` and ``y - dy`` and the shift can be read back."""
    yy, xx = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    image = np.stack([xx, yy], -1).astype(np.float32)
    return jnp.asarray(np.broadcast_to(image, (b, t, h, w, 2)).copy())


def _read_shift(images, margin=4):
    """(dx, dy) per [B, T] from translated ramp images, read in the unclamped interior."""
    images = np.asarray(images, np.float64)
    h, w = images.shape[2:4]
    yy, xx = np.meshgrid(np.arange(h), np.arange(w), indexing="ij")
    inner = (slice(None), slice(None), slice(margin, h - margin), slice(margin, w - margin))
    dx = (xx - images[..., 0])[inner].mean((-2, -1))
    dy = (yy - images[..., 1])[inner].mean((-2, -1))
    return np.stack([dx, dy], -1)  # [B, T, 2]


# ---------------------------------------------------------------- l2_normalize, sinkhorn


def test_l2_normalize_matches_tf_formula():
    """tf.math.l2_normalize (used by common/nets.py proto_loss and dreamerv2/agent.py ema_proj):
    x · rsqrt(max(Σ x², 1e-12)); a zero vector stays zero."""
    x = np.array([[3.0, 4.0], [0.0, 0.0], [1e-7, 0.0]], np.float32)
    expected = x / np.sqrt(np.maximum((x.astype(np.float64) ** 2).sum(-1, keepdims=True), 1e-12))
    np.testing.assert_allclose(l2_normalize(jnp.asarray(x)), expected, rtol=1e-6)
    np.testing.assert_allclose(l2_normalize(jnp.asarray(x))[0], [0.6, 0.8], rtol=1e-6)


def test_sinkhorn_three_iterations_equal_release_loop():
    """common/nets.py RSSM.sinkhorn: log Q = log_softmax(scores / ε) over all K·N entries,
    then 3 × (row: - logsumexp_n - log K; column: - logsumexp_k - log N), Q = exp(log Q + log N)
    (the numpy transcription _np_sinkhorn); the last step is a column one, so columns sum to 1."""
    scores = np.random.default_rng(1).uniform(-1, 1, size=(5, 2, 3)).astype(np.float32)
    q = np.asarray(sinkhorn(jnp.asarray(scores), 0.05, 3))
    assert q.shape == scores.shape
    np.testing.assert_allclose(q, _np_sinkhorn(scores, 0.05, 3), rtol=1e-4, atol=1e-6)
    np.testing.assert_allclose(q.reshape(5, -1).sum(0), 1.0, rtol=1e-5)
    # three iterations are not converged: the rows are not yet all N/K
    assert np.abs(q.reshape(5, -1).sum(1) - 6 / 5).max() > 1e-3


def test_sinkhorn_marginals_converge():
    """common/nets.py RSSM.sinkhorn's fixed point: every column (sample) of Q sums to 1 and
    every row (prototype) to N/K, the equipartition of the N samples over K prototypes."""
    k, n = 4, 15
    scores = np.random.default_rng(2).normal(size=(k, 3, 5)).astype(np.float32)
    q = np.asarray(sinkhorn(jnp.asarray(scores), 0.5, 50)).reshape(k, n)
    np.testing.assert_allclose(q.sum(0), 1.0, rtol=1e-5)
    np.testing.assert_allclose(q.sum(1), n / k, rtol=1e-4)
    assert (q > 0).all()


def test_sinkhorn_is_invariant_to_a_constant_shift():
    """common/nets.py RSSM.sinkhorn: log_softmax(s/ε + c/ε) = log_softmax(s/ε), so Q(s + c) =
    Q(s) (and the row/column steps never see c)."""
    scores = jnp.asarray(np.random.default_rng(3).normal(size=(6, 8)), jnp.float32)
    np.testing.assert_allclose(
        sinkhorn(scores + 7.0, 0.5, 3), sinkhorn(scores, 0.5, 3), rtol=1e-4, atol=1e-6
    )


def test_sinkhorn_small_eps_is_near_one_hot():
    """common/nets.py RSSM.sinkhorn with ε → 0: exp(s/ε) concentrates every column of Q on one
    prototype (its column still sums to 1), the hard assignment that the release's ε = 0.05
    softens. Scores plant a balanced assignment (each prototype preferred by 2 of N = 2K
    samples, margin 1 over noise of 0.1), which Q recovers."""
    rng = np.random.default_rng(4)
    k, n = 5, 10
    planted = rng.permutation(np.arange(n) % k)
    scores = (0.1 * rng.normal(size=(k, n)) + np.eye(k)[:, planted]).astype(np.float32)
    q = np.asarray(sinkhorn(jnp.asarray(scores), 1e-3, 3))
    np.testing.assert_allclose(q.sum(0), 1.0, rtol=1e-5)
    assert q.max(0).min() > 0.99
    np.testing.assert_array_equal(q.argmax(0), planted)
    # a large ε is far from one-hot
    assert np.asarray(sinkhorn(jnp.asarray(scores), 10.0, 3)).max(0).max() < 0.5


# ---------------------------------------------------------------- prototype losses


def test_prototype_losses_equal_release_proto_loss():
    """common/nets.py RSSM.proto_loss: swav = -½ mean Σ_k Q2 log P1 - ½ mean Σ_k Q1 log P2,
    temp = -mean Σ_k [Q1; Q2] log P_feat, norm = mean(|obs|-1)² + mean(|feat|-1)², with
    P = softmax_k(c·z/τ) of the unit projections, Q = sinkhorn of each view's EMA scores, the
    first warm_up steps dropped (re-derived in _np_proto_loss, float64)."""
    protos, obs, feat, ema = _inputs()
    out = prototype_losses(*map(jnp.asarray, (protos, obs, feat, ema)), **HPARAMS)
    ref = _np_proto_loss(protos, obs, feat, ema, 0.1, 0.05, 3, 1)
    assert set(out) == {"swav", "temp", "norm"}
    for name in out:
        assert out[name].dtype == jnp.float32 and out[name].shape == ()
        np.testing.assert_allclose(out[name], ref[name], rtol=1e-4, err_msg=name)
    # the swap is real: pairing each view with its own targets gives another value
    unswapped = _np_proto_loss(protos, obs, feat, ema, 0.1, 0.05, 3, 1, swap=False)["swav"]
    assert abs(unswapped - ref["swav"]) > 1e-2


def test_prototype_losses_cast_bfloat16_inputs_to_float32():
    """common/nets.py RSSM.proto_loss casts the projections to float32 (tf.cast(..., float32))
    before any score: bfloat16 inputs give the float32 losses of the same (rounded) values."""
    protos, obs, feat, ema = _inputs(seed=5)
    low = [jnp.asarray(a, jnp.bfloat16) for a in (protos, obs, feat, ema)]
    out = prototype_losses(*low, **HPARAMS)
    ref = _np_proto_loss(*(np.asarray(a, np.float32) for a in low), 0.1, 0.05, 3, 1)
    for name in out:
        assert out[name].dtype == jnp.float32
        np.testing.assert_allclose(out[name], ref[name], rtol=1e-4, err_msg=name)


def test_warm_up_drops_the_first_steps_except_for_norm():
    """common/nets.py RSSM.proto_loss slices every score ``[:, :, warm_up:]`` but takes obs_norm
    and feat_norm over all T: changing step 0 leaves swav and temp unchanged, changes norm; with
    warm_up = 0 swav changes too."""
    protos, obs, feat, ema = _inputs(seed=6)
    obs2, feat2, ema2 = obs.copy(), feat.copy(), ema.copy()
    rng = np.random.default_rng(7)
    obs2[:, 0] = rng.normal(size=obs2[:, 0].shape) * 3
    feat2[:, 0] = rng.normal(size=feat2[:, 0].shape) * 3
    ema2[:, 0] = _np_unit(rng.normal(size=ema2[:, 0].shape))
    base = prototype_losses(*map(jnp.asarray, (protos, obs, feat, ema)), **HPARAMS)
    moved = prototype_losses(*map(jnp.asarray, (protos, obs2, feat2, ema2)), **HPARAMS)
    np.testing.assert_allclose(moved["swav"], base["swav"], rtol=1e-6)
    np.testing.assert_allclose(moved["temp"], base["temp"], rtol=1e-6)
    assert abs(float(moved["norm"]) - float(base["norm"])) > 1e-2
    no_warm = dict(HPARAMS, warm_up=0)
    base0 = prototype_losses(*map(jnp.asarray, (protos, obs, feat, ema)), **no_warm)
    moved0 = prototype_losses(*map(jnp.asarray, (protos, obs2, feat2, ema2)), **no_warm)
    assert abs(float(moved0["swav"]) - float(base0["swav"])) > 1e-3
    np.testing.assert_allclose(
        base0["swav"], _np_proto_loss(protos, obs, feat, ema, 0.1, 0.05, 3, 0)["swav"], rtol=1e-4
    )


def test_sinkhorn_runs_per_view():
    """common/nets.py RSSM.proto_loss: ema_targets_1 and ema_targets_2 are two Sinkhorns, one
    per half of the batch, not one over both views. temp with the per-view targets differs from
    temp with one joint Sinkhorn over all 2 B0 (T - w) samples (numpy). And with zero feat_proj
    (unit-normalised to 0, so log P_feat = -log K everywhere) temp = log K, as every target
    column sums to 1."""
    protos, obs, feat, ema = _inputs(seed=8)
    out = prototype_losses(*map(jnp.asarray, (protos, obs, np.zeros_like(feat), ema)), **HPARAMS)
    np.testing.assert_allclose(out["temp"], np.log(protos.shape[0]), rtol=1e-5)
    # joint Sinkhorn over both views (what the release does not do) gives another temp
    b = obs.shape[0]
    scores = (protos.astype(np.float64) @ ema.reshape(-1, 4).T).reshape(6, b, -1)[:, :, 1:]
    joint = _np_sinkhorn(scores, 0.05, 3)
    feat_logits = _np_log_softmax(
        (protos @ _np_unit(feat).reshape(-1, 4).T).reshape(6, b, -1)[:, :, 1:] / 0.1, 0
    )
    joint_temp = -(joint * feat_logits).sum(0).mean()
    per_view = prototype_losses(*map(jnp.asarray, (protos, obs, feat, ema)), **HPARAMS)["temp"]
    assert abs(joint_temp - float(per_view)) > 1e-3


def test_norm_loss_is_zero_for_unit_projections():
    """common/nets.py RSSM.proto_loss: norm = mean(|obs_proj| - 1)² + mean(|feat_proj| - 1)²
    vanishes when both projections are unit vectors, and equals 2·(2-1)² = 2 when all have
    norm 2."""
    protos, obs, feat, ema = _inputs(seed=9)
    unit = prototype_losses(
        *map(jnp.asarray, (protos, _np_unit(obs), _np_unit(feat), ema)), **HPARAMS
    )
    np.testing.assert_allclose(unit["norm"], 0.0, atol=1e-6)
    double = prototype_losses(
        *map(jnp.asarray, (protos, 2 * _np_unit(obs), 2 * _np_unit(feat), ema)), **HPARAMS
    )
    np.testing.assert_allclose(double["norm"], 2.0, rtol=1e-5)
    # the normalised directions, not the norms, set swav and temp
    np.testing.assert_allclose(double["swav"], unit["swav"], rtol=1e-5)
    np.testing.assert_allclose(double["temp"], unit["temp"], rtol=1e-5)


def test_gradients_skip_the_targets():
    """dreamerv2/agent.py WorldModel.loss: ema_proj = tf.stop_gradient(self.ema_proj(data)), and
    common/nets.py proto_loss: tf.stop_gradient(self.sinkhorn(...)): no gradient reaches
    ema_proj, and the prototypes' gradient is that of -Σ Q log P with Q held constant (computed
    here from the numpy Sinkhorn); prototypes, obs_proj and feat_proj all get a gradient."""
    protos, obs, feat, ema = map(jnp.asarray, _inputs(seed=10))

    def total(p, o, f, e):
        return sum(prototype_losses(p, o, f, e, **HPARAMS).values())

    g_p, g_o, g_f, g_e = jax.grad(total, argnums=(0, 1, 2, 3))(protos, obs, feat, ema)
    assert np.all(np.asarray(g_e) == 0)
    for g in (g_p, g_o, g_f):
        assert np.abs(np.asarray(g)).max() > 1e-4

    # constant targets from the numpy Sinkhorn
    b = obs.shape[0]
    ema_scores = (np.asarray(protos, np.float64) @ np.asarray(ema).reshape(-1, 4).T).reshape(
        6, b, -1
    )[:, :, 1:]
    q1 = jnp.asarray(_np_sinkhorn(ema_scores[:, : b // 2], 0.05, 3), jnp.float32)
    q2 = jnp.asarray(_np_sinkhorn(ema_scores[:, b // 2 :], 0.05, 3), jnp.float32)

    def fixed_target_loss(p):
        def logp(z):
            z = z / jnp.linalg.norm(z, axis=-1, keepdims=True)
            s = jnp.einsum("kd,btd->kbt", p, z, precision="highest")[:, :, 1:]
            return jax.nn.log_softmax(s / 0.1, axis=0)

        lo, lf = logp(obs), logp(feat)
        swav = (
            -0.5 * (q2 * lo[:, : b // 2]).sum(0).mean() - 0.5 * (q1 * lo[:, b // 2 :]).sum(0).mean()
        )
        return swav - (jnp.concatenate([q1, q2], 1) * lf).sum(0).mean()

    np.testing.assert_allclose(g_p, jax.grad(fixed_target_loss)(protos), rtol=1e-3, atol=1e-5)


# ---------------------------------------------------------------- EMA and freezing


def test_ema_update_copies_first_then_mixes():
    """dreamerv2/agent.py WorldModel.ema_update: mix = 1.0 if updates == 0 else
    ema_update_fraction (0.05 in configs.yaml); d ← mix·s + (1 - mix)·d for every variable."""
    online = {"w": jnp.array([1.0, 2.0]), "b": {"c": jnp.array(3.0)}}
    target = {"w": jnp.array([0.0, 1.0]), "b": {"c": jnp.array(-1.0)}}
    update = jax.jit(ema_update, static_argnums=2)
    copied = update(online, target, 0.05, jnp.array(True))
    np.testing.assert_array_equal(copied["w"], [1.0, 2.0])
    np.testing.assert_array_equal(copied["b"]["c"], 3.0)
    mixed = update(online, target, 0.05, jnp.array(False))
    # 0.05·1 + 0.95·0 = 0.05;  0.05·2 + 0.95·1 = 1.05;  0.05·3 + 0.95·(-1) = -0.8
    np.testing.assert_allclose(mixed["w"], [0.05, 1.05], rtol=1e-6)
    np.testing.assert_allclose(mixed["b"]["c"], -0.8, rtol=1e-6)
    assert mixed["w"].dtype == target["w"].dtype


def test_freeze_zeroes_or_passes_gradients():
    """dreamerv2/agent.py WorldModel.train: if updates < freeze_prototypes_iters, the
    prototypes' gradient is tf.zeros_like(...); otherwise it is applied unchanged."""
    grads = {"prototypes": jnp.array([[1.0, -2.0], [0.5, 3.0]])}
    fn = jax.jit(freeze)
    np.testing.assert_array_equal(fn(grads, jnp.array(True))["prototypes"], np.zeros((2, 2)))
    np.testing.assert_array_equal(fn(grads, jnp.array(False))["prototypes"], grads["prototypes"])
    step, iters = jnp.array(9999), 10000
    np.testing.assert_array_equal(fn(grads, step < iters)["prototypes"], np.zeros((2, 2)))


# ---------------------------------------------------------------- translation


def test_translate_by_integer_shift_moves_pattern_with_edge_replication():
    """common/other.py random_translate → tfa.image.translate([dx, dy], bilinear, nearest):
    tfa's transform [1, 0, -dx, 0, 1, -dy, 0, 0] reads output (x, y) from input
    (x - dx, y - dy), clamped into the image (fill_mode nearest); an integer shift moves the
    pattern by exactly (dx, dy) pixels (dx to the right along W, dy down along H) and repeats
    the edge rows/columns into the uncovered border."""
    h, w = 5, 6
    base = (10 * np.arange(h)[:, None] + np.arange(w)[None, :]).astype(np.float32)
    frames = np.stack([base, base + 100], 0)[..., None]  # [T=2, H, W, 1]
    images = jnp.asarray(np.stack([frames, frames], 0))  # [B=2, ...]
    shifts = jnp.array([[2.0, -1.0], [-1.0, 2.0]])
    out = np.asarray(translate_by(images, shifts))
    for b, (dx, dy) in enumerate([(2, -1), (-1, 2)]):
        rows = np.clip(np.arange(h) - dy, 0, h - 1)
        cols = np.clip(np.arange(w) - dx, 0, w - 1)
        for t in range(2):
            np.testing.assert_array_equal(out[b, t, ..., 0], frames[t, ..., 0][np.ix_(rows, cols)])
    # dx = 2: the two leftmost columns both replicate input column 0; dy = -1: bottom row = last
    np.testing.assert_array_equal(out[0, 0, 0, :3, 0], [10.0, 10.0, 10.0])
    np.testing.assert_array_equal(out[0, 0, -1, :, 0], out[0, 0, -2, :, 0])


def test_translate_by_half_pixel_averages_neighbours_and_matches_tf_kernel():
    """tensorflow/core/kernels/image/image_ops.h ProjectiveGenerator, BILINEAR with
    FILL_NEAREST (what tfa.image.translate runs): x' = clamp(x - dx, 0, W-1), then
    (x_ceil - x')·f(x_floor) + (x' - x_floor)·f(x_ceil), likewise along y. A half-pixel dx
    averages horizontal neighbours; random fractional shifts match a numpy transcription."""
    rng = np.random.default_rng(11)
    image = rng.normal(size=(5, 7, 3)).astype(np.float32)
    out = np.asarray(translate_by(jnp.asarray(image)[None, None], jnp.array([[0.5, 0.0]])))[0, 0]
    np.testing.assert_allclose(out[:, 1:], 0.5 * (image[:, :-1] + image[:, 1:]), rtol=1e-5)
    np.testing.assert_allclose(out[:, 0], image[:, 0], rtol=1e-6)  # x' = -0.5 clamps to 0
    shifts = np.array([[1.3, -2.7], [-0.4, 0.9], [3.0, 2.2]], np.float32)
    images = rng.normal(size=(3, 2, 5, 7, 3)).astype(np.float32)
    got = np.asarray(translate_by(jnp.asarray(images), jnp.asarray(shifts)))
    for b, (dx, dy) in enumerate(shifts):
        for t in range(2):
            expected = _np_tf_bilinear_nearest(images[b, t], float(dx), float(dy))
            np.testing.assert_allclose(got[b, t], expected, rtol=1e-5, atol=1e-5)


def test_translate_draws_one_uniform_shift_per_sequence():
    """common/other.py random_translate(same_across_time=True, bilinear=True): delta =
    uniform([B, 1, 2], -max_delta, max_delta) repeated over T: every frame of a sequence moves
    by the same continuous (dx, dy) in [-max_delta, max_delta]; sequences differ; the same key
    gives the same output. Shifts are read back from linear ramps (exact under bilinear)."""
    images = _ramp_images(8, 3)
    key = jax.random.PRNGKey(0)
    out = jax.jit(translate, static_argnums=2)(images, key, 3.0)
    shifts = _read_shift(out)  # [B, T, 2]
    assert np.abs(shifts).max() <= 3.0 + 1e-4
    np.testing.assert_allclose(shifts, np.repeat(shifts[:, :1], 3, 1), atol=1e-4)
    assert np.unique(np.round(shifts[:, 0, 0], 3)).size == 8  # continuous, independent
    assert np.abs(shifts[:, 0, 0] - shifts[:, 0, 1]).min() > 1e-3  # dx, dy drawn apart
    assert np.abs(shifts - np.round(shifts)).max() > 0.05  # not integers
    # same key, same shifts (eager and jitted may differ by float rounding only)
    np.testing.assert_array_equal(translate(images, key, 3.0), translate(images, key, 3.0))
    np.testing.assert_allclose(translate(images, key, 3.0), out, rtol=1e-6, atol=1e-5)
    assert not np.array_equal(np.asarray(translate(images, jax.random.PRNGKey(1), 3.0)), out)
    # max_delta = 0 is the identity
    np.testing.assert_array_equal(np.asarray(translate(images, key, 0.0)), np.asarray(images))


# ---------------------------------------------------------------- two views


def test_two_views_doubles_the_batch_and_shifts_each_copy():
    """dreamerv2/agent.py WorldModel.preprocess(aug=True): obs = {k: concat([v, v], 0)}, then
    random_translate of the whole doubled image batch: every key has 2 B0 rows, non-image
    keys are the batch twice, and the two copies of a sequence get independent shifts."""
    b0, t = 3, 2
    batch = {
        "image": _ramp_images(b0, t) / 16.0 - 0.5,
        "action": jnp.arange(b0 * t * 2, dtype=jnp.float32).reshape(b0, t, 2),
        "reward": jnp.arange(b0 * t, dtype=jnp.float32).reshape(b0, t),
    }
    views = two_views(batch, jax.random.PRNGKey(3), 3.0)
    assert set(views) == set(batch)
    for k, v in views.items():
        assert v.shape == (2 * b0, *batch[k].shape[1:])
    for k in ("action", "reward"):
        np.testing.assert_array_equal(views[k][:b0], batch[k])
        np.testing.assert_array_equal(views[k][b0:], batch[k])
    first, second = np.asarray(views["image"][:b0]), np.asarray(views["image"][b0:])
    assert np.abs(first - second).max() > 1e-2
    shifts = _read_shift((views["image"] + 0.5) * 16.0)
    assert np.abs(shifts[:b0, 0] - shifts[b0:, 0]).min() > 1e-3
    # custom image key
    renamed = two_views({"pixels": batch["image"]}, jax.random.PRNGKey(3), 3.0, "pixels")
    np.testing.assert_array_equal(renamed["pixels"], views["image"])


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.bfloat16])
def test_translate_keeps_dtype_and_shape(dtype):
    """common/other.py random_translate returns tf.reshape(translated, shape): same shape (and
    here the caller's float dtype)."""
    images = jnp.zeros((2, 3, 8, 8, 3), dtype)
    out = translate(images, jax.random.PRNGKey(0), 3.0)
    assert out.shape == images.shape and out.dtype == dtype
