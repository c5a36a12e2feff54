"""Image encoder/decoder and MLP heads of the world model (flax.linen, DreamerV2 layout).

All modules accept any number of leading batch dimensions. Kernels use Glorot-uniform
initialisation (the TensorFlow default the released code relied on); activations are ELU.

Shapes for 64x64 images and depth ``d``::

    encoder: 64 -> 31 -> 14 -> 6 -> 2  (kernel 4, stride 2, VALID; depths d, 2d, 4d, 8d)
             flattened embedding of size 2*2*8d = 32d
    decoder: Dense(32d) -> 1x1 -> 5 -> 13 -> 30 -> 64  (kernels 5, 5, 6, 6, stride 2, VALID;
             depths 4d, 2d, d, channels)
"""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

_GLOROT = nn.initializers.xavier_uniform()
ENCODER_KERNELS = (4, 4, 4, 4)
DECODER_KERNELS = (5, 5, 6, 6)


def image_to_float(image: jax.Array) -> jax.Array:
    """uint8 pixels in [0, 255] -> float32 in [-0.5, 0.5]; float input is taken as already scaled."""
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

    @nn.compact
    def __call__(self, image: jax.Array) -> jax.Array:
        x = image
        for i, kernel in enumerate(ENCODER_KERNELS):
            x = nn.Conv(self.depth * 2**i, (kernel, kernel), strides=(2, 2), padding="VALID",
                        kernel_init=_GLOROT)(x)
            x = nn.elu(x)
        return x.reshape(x.shape[:-3] + (-1,))


class ConvDecoder(nn.Module):
    """[..., F] features -> [..., 64, 64, channels] mean image in [-0.5, 0.5] units."""

    depth: int
    channels: int

    @nn.compact
    def __call__(self, feat: jax.Array) -> jax.Array:
        x = nn.Dense(32 * self.depth, kernel_init=_GLOROT)(feat)
        x = x.reshape(x.shape[:-1] + (1, 1, x.shape[-1]))
        last = len(DECODER_KERNELS) - 1
        for i, kernel in enumerate(DECODER_KERNELS):
            features = self.channels if i == last else self.depth * 2 ** (last - 1 - i)
            x = nn.ConvTranspose(features, (kernel, kernel), strides=(2, 2), padding="VALID",
                                 kernel_init=_GLOROT)(x)
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

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for _ in range(self.layers):
            x = nn.elu(nn.Dense(self.units, kernel_init=_GLOROT)(x))
        size = 1
        for dim in self.out_shape:
            size *= dim
        x = nn.Dense(size, kernel_init=_GLOROT)(x)
        return x.reshape(x.shape[:-1] + tuple(self.out_shape))


def normal_log_prob(mean: jax.Array, target: jax.Array, event_dims: int = 0) -> jax.Array:
    """log N(target | mean, 1), summed over the last ``event_dims`` dimensions."""
    log_prob = -0.5 * jnp.square(target - mean) - 0.5 * jnp.log(2.0 * jnp.pi)
    return log_prob.sum(axis=tuple(range(-event_dims, 0))) if event_dims else log_prob


def bernoulli_log_prob(logits: jax.Array, target: jax.Array) -> jax.Array:
    """log Bernoulli(target | sigmoid(logits)) for targets in [0, 1], stable for any logit."""
    return target * jax.nn.log_sigmoid(logits) + (1.0 - target) * jax.nn.log_sigmoid(-logits)
