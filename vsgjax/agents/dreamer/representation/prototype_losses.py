"""DreamerPro's prototype losses, its two augmented views and its EMA target encoder.

Re-derived from the authors' release (fdeng18/dreamer-pro, ``DreamerPro/``): ``common/nets.py``
``RSSM.sinkhorn`` and ``RSSM.proto_loss``, ``dreamerv2/agent.py`` ``WorldModel.train``,
``preprocess(aug=True)``, ``ema_proj`` and ``ema_update``, ``common/other.py``
``random_translate``. With K prototypes ``c_k`` (unit vectors, [K, D]), a batch of 2 B0
sequences (view 1 then view 2 of the same B0 sequences) of length T, and ``w = warm_up``:

    z = proj / |proj|                     (obs: from the embedding; feat: from the RSSM state)
    P_view(k | b, t) = softmax_k(c_k · z_bt / τ)                  t ≥ w
    Q_view = Sinkhorn(c · z_ema / ε) on the view's B0 (T - w) samples    (no gradient)
    L_swav = -½ mean_{b,t} Σ_k Q2 log P1_obs - ½ mean_{b,t} Σ_k Q1 log P2_obs
    L_temp = -mean_{b,t} Σ_k Q log P_feat                  Q = [Q1; Q2] along the batch
    L_norm = mean_{b,t} (|obs_proj| - 1)² + mean_{b,t} (|feat_proj| - 1)²   (all t, no warm-up)

Everything here is float32 and the score matmuls run at full float32 precision (``HIGHEST``):
Sinkhorn divides the scores by ε = 0.05 (0.0125 for DMC), so a TF32 rounding of the scores
would be amplified 20-80 times in its exponent.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import optax

_HIGHEST = jax.lax.Precision.HIGHEST


def l2_normalize(x: jax.Array, axis: int = -1) -> jax.Array:
    """``x / max(|x|, 1e-6)`` as ``tf.math.l2_normalize``: ``x · rsqrt(max(Σ x², 1e-12))``."""
    sum_sq = jnp.sum(jnp.square(x), axis=axis, keepdims=True)
    return x * jax.lax.rsqrt(jnp.maximum(sum_sq, 1e-12))


def sinkhorn(scores: jax.Array, eps: float, iters: int) -> jax.Array:
    """Sinkhorn-Knopp assignments ``Q`` of N samples to K prototypes, in log space.

    ``scores`` [K, ...] (every axis after the first is a sample axis; N their product)::

        log Q ← log_softmax over all K·N entries of scores / ε,  reshaped [K, N]
        iters times:  log Q ← log Q - logsumexp_n log Q - log K     (rows sum to 1/K)
                      log Q ← log Q - logsumexp_k log Q - log N     (columns sum to 1/N)
        Q = exp(log Q + log N)

    so each column (sample) of Q sums to 1 and, once converged, each row to N/K.
    """
    shape = scores.shape
    num_protos = shape[0]
    log_q = jax.nn.log_softmax((scores / eps).reshape(-1)).reshape(num_protos, -1)
    num_samples = log_q.shape[1]
    for _ in range(iters):
        log_q = log_q - jax.nn.logsumexp(log_q, axis=1, keepdims=True) - math.log(num_protos)
        log_q = log_q - jax.nn.logsumexp(log_q, axis=0, keepdims=True) - math.log(num_samples)
    return jnp.exp(log_q + math.log(num_samples)).reshape(shape)


def _scores(prototypes: jax.Array, proj: jax.Array, warm_up: int) -> jax.Array:
    """``c_k · z_bt`` [K, B, T - warm_up] from unit ``proj`` [B, T, D]."""
    return jnp.einsum("kd,btd->kbt", prototypes, proj, precision=_HIGHEST)[:, :, warm_up:]


def prototype_losses(
    prototypes: jax.Array,
    obs_proj: jax.Array,
    feat_proj: jax.Array,
    ema_proj: jax.Array,
    *,
    temperature: float,
    sinkhorn_eps: float,
    sinkhorn_iters: int,
    warm_up: int,
) -> dict[str, jax.Array]:
    """``{"swav", "temp", "norm"}`` (module docstring), float32 scalars.

    ``prototypes`` [K, D] unit rows; ``obs_proj``, ``feat_proj`` [B, T, D] the raw projections
    (normalised here; their norms feed ``norm``); ``ema_proj`` [B, T, D] the unit EMA
    projections, the targets' source (no gradient reaches it, nor the prototypes through it).
    The batch axis is two views: rows ``[:B/2]`` view 1, ``[B/2:]`` view 2.
    """
    prototypes = prototypes.astype(jnp.float32)
    obs_proj, feat_proj, ema_proj = (x.astype(jnp.float32) for x in (obs_proj, feat_proj, ema_proj))
    obs_norm = jnp.linalg.norm(obs_proj, axis=-1)
    feat_norm = jnp.linalg.norm(feat_proj, axis=-1)

    obs_logp = jax.nn.log_softmax(
        _scores(prototypes, l2_normalize(obs_proj), warm_up) / temperature, axis=0
    )
    feat_logp = jax.nn.log_softmax(
        _scores(prototypes, l2_normalize(feat_proj), warm_up) / temperature, axis=0
    )
    obs_logp_1, obs_logp_2 = jnp.split(obs_logp, 2, axis=1)

    # Targets: one Sinkhorn per view, over that view's B0 (T - w) samples.
    ema_1, ema_2 = jnp.split(_scores(prototypes, ema_proj, warm_up), 2, axis=1)
    q_1 = jax.lax.stop_gradient(sinkhorn(ema_1, sinkhorn_eps, sinkhorn_iters))
    q_2 = jax.lax.stop_gradient(sinkhorn(ema_2, sinkhorn_eps, sinkhorn_iters))
    q = jnp.concatenate([q_1, q_2], axis=1)

    # Swapped prediction: view 1 predicts view 2's target and vice versa.
    swav = -0.5 * jnp.mean(jnp.sum(q_2 * obs_logp_1, axis=0)) - 0.5 * jnp.mean(
        jnp.sum(q_1 * obs_logp_2, axis=0)
    )
    temp = -jnp.mean(jnp.sum(q * feat_logp, axis=0))
    norm = jnp.mean(jnp.square(obs_norm - 1.0)) + jnp.mean(jnp.square(feat_norm - 1.0))
    return {"swav": swav, "temp": temp, "norm": norm}


def _shift_axis(images: jax.Array, shift: jax.Array, axis: int) -> jax.Array:
    """Linear interpolation of ``out[i] = in[clip(i - shift, 0, n - 1)]`` along ``axis``."""
    n = images.shape[axis]
    src = jnp.clip(jnp.arange(n, dtype=jnp.float32) - shift, 0.0, n - 1.0)
    lo = jnp.floor(src)
    frac = (src - lo).astype(images.dtype)
    lo = lo.astype(jnp.int32)
    hi = jnp.minimum(lo + 1, n - 1)
    weight_shape = [1] * images.ndim
    weight_shape[axis] = n
    frac = frac.reshape(weight_shape)
    return (1 - frac) * jnp.take(images, lo, axis=axis) + frac * jnp.take(images, hi, axis=axis)


def translate_by(images: jax.Array, shifts: jax.Array) -> jax.Array:
    """``tfa.image.translate(..., interpolation="bilinear", fill_mode="nearest")`` per sequence.

    ``images`` [B, T, H, W, C] float, ``shifts`` [B, 2] as ``(dx, dy)`` (dx along W, dy along
    H), one per sequence for all its frames::

        out[y, x] = in(clip(y - dy, 0, H - 1), clip(x - dx, 0, W - 1))

    bilinearly interpolated (tfa's transform row ``[1, 0, -dx, 0, 1, -dy, 0, 0]`` maps an
    output point to the input point it reads; the ``nearest`` fill clamps that point into the
    image, i.e. replicates the edge). A translation's bilinear weights factor into one along y
    times one along x, so it is applied as two 1-D interpolations.
    """

    def one(seq, shift):  # seq [T, H, W, C]
        return _shift_axis(_shift_axis(seq, shift[1], axis=1), shift[0], axis=2)

    return jax.vmap(one)(images, shifts.astype(jnp.float32))


def translate(images: jax.Array, key: jax.Array, max_delta: float) -> jax.Array:
    """``random_translate(bilinear=True, same_across_time=True)``: one ``(dx, dy)`` per sequence,
    uniform in ``[-max_delta, max_delta]``², shared by its T frames. ``images`` [B, T, H, W, C]."""
    shifts = jax.random.uniform(key, (images.shape[0], 2), minval=-max_delta, maxval=max_delta)
    return translate_by(images, shifts)


def two_views(
    batch: dict[str, jax.Array], key: jax.Array, max_delta: float, image_key: str = "image"
) -> dict[str, jax.Array]:
    """``preprocess(aug=True)``: every [B0, T, ...] entry concatenated with itself on the batch
    axis ([2 B0, T, ...]), then the (already float) image of the doubled batch translated, so
    the two copies of a sequence get independent shifts."""
    doubled = {k: jnp.concatenate([v, v], axis=0) for k, v in batch.items()}
    doubled[image_key] = translate(doubled[image_key], key, max_delta)
    return doubled


def ema_update(online, target, fraction: float, first: jax.Array):
    """``target ← mix · online + (1 - mix) · target`` leafwise, ``mix = 1`` (a copy) where
    ``first`` (the release's first update) else ``fraction``."""
    return optax.incremental_update(online, target, jnp.where(first, 1.0, fraction))


def freeze(grads, frozen: jax.Array):
    """``grads`` with every leaf zeroed where ``frozen`` (the release zeroes the prototypes'
    gradient while ``updates < freeze_prototypes_iters``), else unchanged."""
    return jax.tree.map(lambda g: jnp.where(frozen, jnp.zeros_like(g), g), grads)
