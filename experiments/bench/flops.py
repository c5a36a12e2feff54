"""Count the FLOPs of a JAX function from its jaxpr, with scan bodies counted once per step.

XLA's ``cost_analysis()`` counts the body of a ``while`` loop (what ``lax.scan`` lowers to)
once, whatever its trip count, so a 50-step recurrent update is undercounted ~50x in its
recurrent part. Here every ``scan`` body is multiplied by its ``length`` and nested jaxprs
(``pjit``, ``custom_vjp``, ``remat``, ``cond`` = most expensive branch) are walked.

Only ``dot_general`` and ``conv_general_dilated`` are counted (2 FLOPs per multiply-add): they
are the work that a matmul FLOP rate is comparable to. Convolutions count *useful*
multiply-adds only: for transposed / input-dilated convolutions (the decoder, and the input
gradient of strided convolutions) the multiplications with inserted zeros and with padding are
left out, so the figure does not depend on how XLA happens to lower a transposed convolution.
"""

from __future__ import annotations

import math

import jax
import numpy as np
from jax.extend import core


def _sub_jaxprs(params: dict):
    for value in params.values():
        items = value if isinstance(value, (list, tuple)) else (value,)
        for item in items:
            if isinstance(item, core.ClosedJaxpr):
                yield item.jaxpr
            elif isinstance(item, core.Jaxpr):
                yield item


def _dot_flops(eqn) -> int:
    (_, rhs_contract), (_, rhs_batch) = eqn.params["dimension_numbers"]
    lhs, rhs = (v.aval.shape for v in eqn.invars)
    rhs_free = math.prod(d for i, d in enumerate(rhs) if i not in (*rhs_contract, *rhs_batch))
    return 2 * math.prod(lhs) * rhs_free


def _useful_taps(n: int, k: int, out: int, stride: int, pad_lo: int, lhs_dil: int,
                 rhs_dil: int) -> int:
    """(output position, kernel tap) pairs of one spatial dim that read a real input element."""
    o = np.arange(out)[:, None]
    j = np.arange(k)[None, :]
    pos = o * stride + j * rhs_dil - pad_lo
    real = (pos >= 0) & (pos <= (n - 1) * lhs_dil) & (pos % lhs_dil == 0)
    return int(real.sum())


def _conv_flops(eqn) -> int:
    p = eqn.params
    dims = p["dimension_numbers"]
    lhs, rhs = (v.aval.shape for v in eqn.invars)
    out = eqn.outvars[0].aval.shape
    taps = 1
    for i, (l_dim, r_dim, o_dim) in enumerate(zip(dims.lhs_spec[2:], dims.rhs_spec[2:],
                                                  dims.out_spec[2:], strict=True)):
        taps *= _useful_taps(lhs[l_dim], rhs[r_dim], out[o_dim], p["window_strides"][i],
                             p["padding"][i][0], p["lhs_dilation"][i], p["rhs_dilation"][i])
    batch, out_features = out[dims.out_spec[0]], out[dims.out_spec[1]]
    in_features = rhs[dims.rhs_spec[1]]  # per feature group
    return 2 * batch * out_features * in_features * taps


def jaxpr_flops(jaxpr: core.Jaxpr) -> int:
    """Matmul + convolution FLOPs of a jaxpr, scan bodies multiplied by their length."""
    total = 0
    for eqn in jaxpr.eqns:
        name = eqn.primitive.name
        if name == "dot_general":
            total += _dot_flops(eqn)
        elif name == "conv_general_dilated":
            total += _conv_flops(eqn)
        elif name == "cond":
            total += max(jaxpr_flops(b.jaxpr) for b in eqn.params["branches"])
        else:
            inner = sum(jaxpr_flops(sub) for sub in _sub_jaxprs(eqn.params))
            total += inner * (eqn.params["length"] if name == "scan" else 1)
    return total


def count_flops(fn, *args, **kwargs) -> int:
    """FLOPs (matmuls and convolutions) of one call ``fn(*args, **kwargs)``.

    ``fn`` is traced through a fresh wrapper: ``jax.make_jaxpr`` caches traces per function
    object, so tracing ``fn`` itself a second time (e.g. with the convolutions patched) would
    return the first trace.
    """
    def fresh(*a, **k):
        return fn(*a, **k)

    return jaxpr_flops(jax.make_jaxpr(fresh)(*args, **kwargs).jaxpr)
