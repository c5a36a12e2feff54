"""Mixed precision (``model.precision``): float32 parameters, bfloat16 matmuls.

The policy, one rule: every dense layer and every im2col / phase matmul of the stride-2
(transposed) convolutions goes through :func:`matmul`, which casts its two inputs (activations
and kernel) to the compute dtype and accumulates and returns float32. Nothing else is cast, so
everything after a matmul is float32 again: biases, ELU/tanh/sigmoid (the GRU's
nonlinearities), LayerNorm, the latent distributions and their samples, the straight-through
gate samples of VSG/SVSG (exactly 0/1), KL, the gate sparsity loss, log-probabilities,
λ-returns. Parameters, gradients and optimizer state stay float32 (the cast's transpose turns
the bfloat16 gradient of a kernel back into float32).

``float32`` is today's computation bit for bit: the casts are no-ops and the float32 product
is what ``x @ kernel`` computes.

The authors' release trained in float16 with (dynamic) loss scaling, because float16's 5
exponent bits underflow on small gradients. bfloat16 keeps float32's 8 exponent bits (only the
mantissa is shorter: 8 bits against 24), so nothing underflows that would not in float32 and
no loss scaling is needed; there is none here.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from vsgjax.config import PRECISIONS


def compute_dtype(name: str) -> jnp.dtype:
    """The matmul input dtype of the precision ``name`` (one of ``vsgjax.config.PRECISIONS``)."""
    if name not in PRECISIONS:
        raise ValueError(f"unknown model.precision {name!r}; valid: {', '.join(PRECISIONS)}")
    return jnp.dtype(name)


def matmul(x: jax.Array, w: jax.Array, dtype=jnp.float32) -> jax.Array:
    """``x [..., K] @ w [K, N] -> [..., N]`` float32, with both inputs cast to ``dtype`` first.

    One ``dot_general`` over the last axis of ``x`` and the first of ``w`` (as ``flax``'s
    ``nn.Dense``), float32 accumulation and output (``preferred_element_type``). In float32
    this is exactly ``x @ w``; otherwise see :func:`_cast_matmul` for the gradient.
    """
    if jnp.dtype(dtype) == jnp.float32:
        return _dot(x, w)
    return _cast_matmul(x.astype(jnp.float32), w.astype(jnp.float32), jnp.dtype(dtype))


def _dot(x: jax.Array, w: jax.Array) -> jax.Array:
    """``x [..., K] @ w [K, N]`` with float32 output."""
    return jax.lax.dot_general(x, w, (((x.ndim - 1,), (0,)), ((), ())),
                               preferred_element_type=jnp.float32)


@functools.partial(jax.custom_vjp, nondiff_argnums=(2,))
def _cast_matmul(x: jax.Array, w: jax.Array, dtype: jnp.dtype) -> jax.Array:
    """float32 ``x``, ``w`` -> ``x.astype(dtype) @ w.astype(dtype)``, float32 out.

    The custom VJP keeps the two backward products in ``dtype`` too: with ``g`` the float32
    cotangent rounded to ``dtype``, ``dx = g @ wᵀ`` and ``dw = xᵀ @ g`` (summed over the
    leading axes), both accumulated and returned in float32. Plain autodiff would transpose
    the forward product into ``float32 g`` times ``bfloat16 w``, which XLA computes in float32,
    leaving two thirds of the matmul work in float32. Residuals are the cast inputs (half the
    memory of float32 ones).
    """
    return _dot(x.astype(dtype), w.astype(dtype))


def _cast_matmul_fwd(x, w, dtype):
    x, w = x.astype(dtype), w.astype(dtype)
    return _dot(x, w), (x, w)


def _cast_matmul_bwd(dtype, residuals, g):
    x, w = residuals
    g = g.astype(dtype)
    lead = tuple(range(x.ndim - 1))
    dx = jax.lax.dot_general(g, w, (((g.ndim - 1,), (1,)), ((), ())),
                             preferred_element_type=jnp.float32)
    dw = jax.lax.dot_general(x, g, ((lead, lead), ((), ())), preferred_element_type=jnp.float32)
    return dx, dw


_cast_matmul.defvjp(_cast_matmul_fwd, _cast_matmul_bwd)
