"""Image and vector encoders/decoders and MLP heads of the world model (flax.linen, DreamerV2).

All modules accept any number of leading batch dimensions. Kernels use Glorot-uniform
initialisation (the TensorFlow default the released code relied on); activations are ELU.
Every module's ``dtype`` is the compute dtype of its matmuls (:mod:`vsgjax.agents.precision`):
parameters are float32 and every output is float32.

Vector observations go through :class:`MLPEncoder` and :class:`MLPDecoder` (one output head
per vector key). Shapes for 64x64 images and depth ``d``::

    encoder: 64 -> 31 -> 14 -> 6 -> 2  (kernel 4, stride 2, VALID; depths d, 2d, 4d, 8d)
             flattened embedding of size 2*2*8d = 32d
    decoder: Dense(32d) -> 1x1 -> 5 -> 13 -> 30 -> 64  (kernels 5, 5, 6, 6, stride 2, VALID;
             depths 4d, 2d, d, channels)
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from vsgjax.agents.precision import matmul

_GLOROT = nn.initializers.xavier_uniform()
ENCODER_KERNELS = (4, 4, 4, 4)
DECODER_KERNELS = (5, 5, 6, 6)
HEAD_PREFIX = "head_"  # MLPDecoder's output layer of the vector key k is named head_<k>


def image_to_float(image: jax.Array) -> jax.Array:
    """uint8 pixels [0, 255] -> float32 in [-0.5, 0.5]; float input is taken as already scaled."""
    if jnp.issubdtype(image.dtype, jnp.integer):
        return image.astype(jnp.float32) / 255.0 - 0.5
    return image.astype(jnp.float32)


def float_to_image(image: jax.Array) -> jax.Array:
    """Inverse of :func:`image_to_float`: float in [-0.5, 0.5] -> uint8 (clipped, rounded)."""
    return jnp.clip(jnp.round((image + 0.5) * 255.0), 0, 255).astype(jnp.uint8)


def embed_dim(depth: int, image_size: int = 64) -> int:
    """Size of the flattened encoder output for square images of ``image_size`` pixels."""
    size = image_size
    for kernel in ENCODER_KERNELS:
        size = (size - kernel) // 2 + 1
    return size * size * depth * 2 ** (len(ENCODER_KERNELS) - 1)


class ConvEncoder(nn.Module):
    """[..., H, W, C] float image -> [..., embed] (four stride-2 VALID convolutions)."""

    depth: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, image: jax.Array) -> jax.Array:
        x = image
        for i, kernel in enumerate(ENCODER_KERNELS):
            x = Conv2(self.depth * 2**i, kernel, self.dtype)(x)
            x = nn.elu(x)
        return x.reshape(x.shape[:-3] + (-1,))


def conv_stride2(x: jax.Array, kernel: jax.Array, dtype=jnp.float32) -> jax.Array:
    """Stride-2 VALID convolution (correlation) as one matmul over im2col patches.

    ``x`` [..., h, w, Cin], ``kernel`` [K, K, Cin, Cout] -> [..., (h-K)//2+1, (w-K)//2+1, Cout].
    On the CPU this beats XLA's native convolution for every encoder layer (up to 10x for the
    small-spatial, many-channel last layer), forward and backward. ``dtype``: the matmul's
    compute dtype (:func:`vsgjax.agents.precision.matmul`).
    """
    size, _, cin, cout = kernel.shape
    oh, ow = (x.shape[-3] - size) // 2 + 1, (x.shape[-2] - size) // 2 + 1
    patches = jnp.concatenate(
        [x[..., i:i + 2 * oh - 1:2, j:j + 2 * ow - 1:2, :]
         for i in range(size) for j in range(size)], axis=-1)
    return matmul(patches, kernel.reshape(size * size * cin, cout), dtype)


class _Stride2Layer(nn.Module):
    """A ``[K, K, Cin, Cout]`` Glorot kernel and a zero bias around the stride-2 op ``apply_op``
    (its matmuls in ``dtype``)."""

    features: int
    kernel_size: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        shape = (self.kernel_size, self.kernel_size, x.shape[-1], self.features)
        kernel = self.param("kernel", _GLOROT, shape)
        bias = self.param("bias", nn.initializers.zeros, (self.features,))
        return self.apply_op(x, kernel, self.dtype) + bias


class Conv2(_Stride2Layer):
    """Stride-2 VALID convolution with bias (see :func:`conv_stride2`)."""

    apply_op = staticmethod(conv_stride2)


def conv_transpose_stride2(x: jax.Array, kernel: jax.Array, dtype=jnp.float32) -> jax.Array:
    """Stride-2 VALID transposed convolution ``out[2i + k] += x[i] @ kernel[k]`` via matmuls.

    ``x`` [..., h, w, Cin], ``kernel`` [K, K, Cin, Cout] -> [..., 2(h-1)+K, 2(w-1)+K, Cout].
    XLA's CPU convolution with an input dilation (how ``lax.conv_transpose`` is lowered) runs
    ~10x below matmul speed. Instead the output is split into its four stride phases (a, b):
    ``out[2p + a] = Σ_m x[p - m] @ kernel[a + 2m]`` with ``m < M = ceil(K/2)`` (taps with
    ``a + 2m >= K`` are zero), then interleaved (depth to space). The phase sums are one matmul
    over ``M x M`` input patches (im2col); a 1x1 input (the decoder's first layer) needs no
    patches: each pixel times all taps is the output (overlap-add). Overlap-add on larger inputs
    moves less memory forward, but XLA's CPU backward of its shifted adds ran 4-10x slower than
    im2col's (the 30x30 -> 64x64 layer: 6.7 s against 0.67 s forward + backward at batch 800).
    ``dtype``: the matmuls' compute dtype (:func:`vsgjax.agents.precision.matmul`); the shifted sums
    of the overlap-add are float32.
    """
    size, _, cin, cout = kernel.shape
    batch, h, w = x.shape[:-3], x.shape[-3], x.shape[-2]
    m = (size + 1) // 2
    # taps[i, a, j, b] = kernel[2i + a, 2j + b] (zero beyond K)
    taps = jnp.pad(kernel, ((0, 2 * m - size), (0, 2 * m - size), (0, 0), (0, 0)))
    taps = taps.reshape(m, 2, m, 2, cin, cout)
    oh, ow = h + m - 1, w + m - 1
    if h == w == 1:
        phases = _overlap_add(x, taps, oh, ow, dtype)
    else:
        phases = _phase_im2col(x, taps, oh, ow, dtype)
    y = jnp.moveaxis(phases, -3, -4).reshape(batch + (2 * oh, 2 * ow, cout))
    return y[..., : 2 * (h - 1) + size, : 2 * (w - 1) + size, :]


def _phase_im2col(x, taps, oh, ow, dtype):
    """[..., h, w, Cin] -> phases [..., oh, ow, 2, 2, Cout] as one matmul over patches."""
    m, _, _, _, cin, cout = taps.shape
    pad = [(0, 0)] * (x.ndim - 3) + [(m - 1, m - 1), (m - 1, m - 1), (0, 0)]
    x = jnp.pad(x, pad)
    patches = jnp.concatenate(
        [x[..., i:i + oh, j:j + ow, :] for i in range(m) for j in range(m)], axis=-1)
    # patch offset (i, j) reads x[p - (m-1-i)]: tap index m-1-i
    weights = taps[::-1, :, ::-1].transpose(0, 2, 4, 1, 3, 5).reshape(m * m * cin, 4 * cout)
    return matmul(patches, weights, dtype).reshape(x.shape[:-3] + (oh, ow, 2, 2, cout))


def _overlap_add(x, taps, oh, ow, dtype):
    """[..., h, w, Cin] -> phases [..., oh, ow, 2, 2, Cout]: all taps per pixel, shifted sums."""
    m, _, _, _, cin, cout = taps.shape
    z = matmul(x, taps.transpose(4, 0, 2, 1, 3, 5).reshape(cin, m * m * 4 * cout), dtype)
    z = z.reshape(x.shape[:-1] + (m, m, 2, 2, cout))
    lead = [(0, 0)] * (x.ndim - 3)
    return sum(jnp.pad(z[..., i, j, :, :, :], lead + [(i, m - 1 - i), (j, m - 1 - j)]
                       + [(0, 0)] * 3) for i in range(m) for j in range(m))


class ConvTranspose2(_Stride2Layer):
    """Stride-2 VALID transposed convolution with bias (see :func:`conv_transpose_stride2`)."""

    apply_op = staticmethod(conv_transpose_stride2)


class Dense(nn.Module):
    """``nn.Dense`` with a Glorot kernel whose matmul is :func:`vsgjax.agents.precision.matmul`.

    Own rather than ``nn.Dense(dtype=...)``, which would cast the bias and return the compute
    dtype (the policy wants a float32 product and bias). The same class name, parameter names,
    shapes, initialisers and creation order as ``nn.Dense`` keep the parameter trees (the
    ``Dense_<i>`` paths) and their initial values unchanged.
    """

    features: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        kernel = self.param("kernel", _GLOROT, (x.shape[-1], self.features), jnp.float32)
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,), jnp.float32)
        y = matmul(x, kernel, self.dtype)
        return y + bias.reshape((1,) * (y.ndim - 1) + (-1,))  # as nn.Dense: the same program


class ConvDecoder(nn.Module):
    """[..., F] features -> [..., 64, 64, channels] mean image in [-0.5, 0.5] units."""

    depth: int
    channels: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, feat: jax.Array) -> jax.Array:
        x = Dense(32 * self.depth, self.dtype)(feat)
        x = x.reshape(x.shape[:-1] + (1, 1, x.shape[-1]))
        last = len(DECODER_KERNELS) - 1
        for i, kernel in enumerate(DECODER_KERNELS):
            features = self.channels if i == last else self.depth * 2 ** (last - 1 - i)
            x = ConvTranspose2(features, kernel, self.dtype)(x)
            if i != last:
                x = nn.elu(x)
        return x


class MLP(nn.Module):
    """``layers`` ELU dense layers of ``units``, then a linear output of ``out_shape``.

    ``out_shape=()`` gives a scalar per example (the reward/discount/value heads).
    """

    layers: int
    units: int
    out_shape: Sequence[int] = ()
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = elu_layers(x, self.layers, self.units, self.dtype)
        size = 1
        for dim in self.out_shape:
            size *= dim
        x = Dense(size, self.dtype)(x)
        return x.reshape(x.shape[:-1] + tuple(self.out_shape))


def elu_layers(x: jax.Array, layers: int, units: int, dtype) -> jax.Array:
    """``layers`` ELU dense layers of ``units`` (``Dense_<i>``; call inside a compact module)."""
    for _ in range(layers):
        x = nn.elu(Dense(units, dtype)(x))
    return x


class MLPEncoder(nn.Module):
    """[..., D] vector -> [..., units] embedding: ``layers`` ELU dense layers, no linear output
    (DreamerV2's encoder for vector keys; ``layers=0`` passes the vector through)."""

    layers: int
    units: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        return elu_layers(x, self.layers, self.units, self.dtype)


class MLPDecoder(nn.Module):
    """[..., F] features -> ``{key: [..., size]}`` means: ``layers`` shared ELU dense layers,
    then one linear head ``head_<key>`` per vector key (DreamerV2's decoder for vector keys)."""

    layers: int
    units: int
    sizes: tuple[tuple[str, int], ...]
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, feat: jax.Array) -> dict[str, jax.Array]:
        x = elu_layers(feat, self.layers, self.units, self.dtype)
        return {key: Dense(size, self.dtype, name=f"{HEAD_PREFIX}{key}")(x)
                for key, size in self.sizes}


def normal_log_prob(mean: jax.Array, target: jax.Array, event_dims: int = 0) -> jax.Array:
    """log N(target | mean, 1), summed over the last ``event_dims`` dimensions."""
    log_prob = -0.5 * jnp.square(target - mean) - 0.5 * jnp.log(2.0 * jnp.pi)
    return log_prob.sum(axis=tuple(range(-event_dims, 0))) if event_dims else log_prob


def bernoulli_log_prob(logits: jax.Array, target: jax.Array) -> jax.Array:
    """log Bernoulli(target | sigmoid(logits)) for targets in [0, 1], stable for any logit."""
    return target * jax.nn.log_sigmoid(logits) + (1.0 - target) * jax.nn.log_sigmoid(-logits)
