"""DrQ-v2's networks (facebookresearch/drqv2 ``drqv2.py``: ``Encoder``, ``Actor``, ``Critic``)
in flax.linen, with the authors' initialisation (``utils.weight_init``).

Shapes for 84x84 frames stacked 3 deep (9 channels) and ``depth`` = 32::

    encoder: obs / 255 - 0.5 -> 84 -> 41 -> 39 -> 37 -> 35  (3x3 kernels, strides 2, 1, 1, 1,
             VALID, ReLU after each) -> flattened 35 * 35 * 32 = 39,200 features
    actor:   trunk (Dense(feature_dim) -> LayerNorm -> tanh) -> Dense(hidden) ReLU
             Dense(hidden) ReLU Dense(A) -> tanh: the mean action
    critic:  its own trunk -> h; Q1, Q2 each Dense(hidden) ReLU Dense(hidden) ReLU Dense(1)
             on concat(h, action)

Vector observations have no encoder: the trunks read the flat vector. Initialisation as
``utils.weight_init``: orthogonal kernels (gain 1 for dense layers, the ReLU gain sqrt(2) for
convolutions), zero biases. LayerNorm's epsilon is torch's 1e-5. Every module's ``dtype`` is
the compute dtype of its matmuls and convolutions (:mod:`vsgjax.agents.precision`); parameters
and outputs are float32.
"""

from __future__ import annotations

import math
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

from vsgjax.agents.precision import matmul

CONV_KERNEL = 3
CONV_STRIDES = (2, 1, 1, 1)
RELU_GAIN = math.sqrt(2.0)  # torch.nn.init.calculate_gain('relu')
TORCH_LAYER_NORM_EPS = 1e-5  # nn.LayerNorm's default (flax's is 1e-6)


def scale_pixels(obs: jax.Array) -> jax.Array:
    """uint8 pixels [0, 255] -> float32 ``obs / 255 - 0.5`` in [-0.5, 0.5] (``Encoder.forward``)."""
    return obs.astype(jnp.float32) / 255.0 - 0.5


def encoder_size(height: int, width: int, depth: int) -> int:
    """Features of the flattened encoder output for ``height x width`` frames (VALID convs):
    ``encoder_size(84, 84, 32) == 32 * 35 * 35 == 39200`` (the authors' ``repr_dim``)."""
    for stride in CONV_STRIDES:
        height = (height - CONV_KERNEL) // stride + 1
        width = (width - CONV_KERNEL) // stride + 1
    return height * width * depth


class Dense(nn.Module):
    """``nn.Linear`` as ``utils.weight_init`` makes it: orthogonal kernel (gain 1), zero bias;
    the matmul in ``dtype`` (:func:`vsgjax.agents.precision.matmul`), float32 out."""

    features: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        kernel = self.param("kernel", nn.initializers.orthogonal(1.0),
                            (x.shape[-1], self.features), jnp.float32)
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,), jnp.float32)
        return matmul(x, kernel, self.dtype) + bias


class Conv(nn.Module):
    """``nn.Conv2d(k=3, stride)`` with VALID padding as ``utils.weight_init`` makes it:
    orthogonal kernel with the ReLU gain, zero bias. [..., H, W, Cin] -> [..., H', W', Cout]."""

    features: int
    stride: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        shape = (CONV_KERNEL, CONV_KERNEL, x.shape[-1], self.features)
        kernel = self.param("kernel", nn.initializers.orthogonal(RELU_GAIN), shape, jnp.float32)
        bias = self.param("bias", nn.initializers.zeros_init(), (self.features,), jnp.float32)
        lead = x.shape[:-3]
        y = jax.lax.conv_general_dilated(
            x.reshape((-1,) + x.shape[-3:]).astype(self.dtype), kernel.astype(self.dtype),
            (self.stride, self.stride), "VALID", dimension_numbers=("NHWC", "HWIO", "NHWC"),
            preferred_element_type=jnp.float32)
        return y.reshape(lead + y.shape[1:]) + bias


class Encoder(nn.Module):
    """uint8 [..., H, W, C * frame_stack] -> float32 [..., encoder_size] (``Encoder``)."""

    depth: int = 32
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = scale_pixels(obs)
        for i, stride in enumerate(CONV_STRIDES):
            x = nn.relu(Conv(self.depth, stride, self.dtype, name=f"conv{i}")(x))
        return x.reshape(x.shape[:-3] + (-1,))


class Trunk(nn.Module):
    """Dense(feature_dim) -> LayerNorm -> tanh (the ``trunk`` of ``Actor`` and ``Critic``)."""

    feature_dim: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = Dense(self.feature_dim, self.dtype, name="dense")(x)
        x = nn.LayerNorm(epsilon=TORCH_LAYER_NORM_EPS, name="norm")(x)
        return jnp.tanh(x)


class MLP(nn.Module):
    """Dense(hidden) ReLU Dense(hidden) ReLU Dense(out) (``Actor.policy``, ``Critic.Q1/Q2``)."""

    hidden: int
    out: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        x = nn.relu(Dense(self.hidden, self.dtype, name="dense0")(x))
        x = nn.relu(Dense(self.hidden, self.dtype, name="dense1")(x))
        return Dense(self.out, self.dtype, name="dense2")(x)


class Actor(nn.Module):
    """Features [..., repr] -> the mean action tanh(policy(trunk(features))) [..., A]
    (``Actor.forward``; the std comes from the schedule, not the network)."""

    action_dim: int
    feature_dim: int
    hidden: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, feat: jax.Array) -> jax.Array:
        h = Trunk(self.feature_dim, self.dtype, name="trunk")(feat)
        return jnp.tanh(MLP(self.hidden, self.action_dim, self.dtype, name="policy")(h))


class Critic(nn.Module):
    """Features [..., repr], action [..., A] -> (Q1, Q2), each [..., 1] (``Critic.forward``)."""

    feature_dim: int
    hidden: int
    dtype: Any = jnp.float32

    @nn.compact
    def __call__(self, feat: jax.Array, action: jax.Array) -> tuple[jax.Array, jax.Array]:
        h = Trunk(self.feature_dim, self.dtype, name="trunk")(feat)
        h_action = jnp.concatenate([h, action.astype(h.dtype)], axis=-1)
        q1 = MLP(self.hidden, 1, self.dtype, name="q1")(h_action)
        q2 = MLP(self.hidden, 1, self.dtype, name="q2")(h_action)
        return q1, q2
