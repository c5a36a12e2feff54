"""DrQ-v2's random-shift augmentation (facebookresearch/drqv2 ``drqv2.py``: ``RandomShiftsAug``).

The authors pad each image by ``pad`` pixels replicating its edges (``F.pad(..., 'replicate')``),
then resample it with ``F.grid_sample`` (bilinear, ``align_corners=False``) on a grid of the
unpadded size shifted by an integer ``s`` in [0, 2 pad] per sample and axis. Their grid's
points are ``g_k = -1 + (2k + 1) / N`` (``linspace(-1 + 1/N, 1 - 1/N, N)[:h]``, N = h + 2 pad)
plus ``2 s / N``; ``grid_sample`` maps ``g`` to the pixel coordinate ``((g + 1) N - 1) / 2 =
k + s``, an integer, where bilinear interpolation returns that pixel exactly. So the augmentation
is an integer crop of the padded image at offset ``s``: that is what runs here (on uint8, no
interpolation arithmetic); tests/agents/drqv2/test_drqv2.py checks the two agree.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp


def shift_crop(images: jax.Array, offsets: jax.Array, pad: int) -> jax.Array:
    """Edge-pad ``images`` [B, H, W, C] by ``pad`` and crop [H, W] back at ``offsets`` [B, 2]
    (row, column; each in [0, 2 pad]). Keeps the dtype."""
    height, width, channels = images.shape[-3:]
    padded = jnp.pad(images, ((0, 0), (pad, pad), (pad, pad), (0, 0)), mode="edge")

    def crop(image, offset):
        return jax.lax.dynamic_slice(image, (offset[0], offset[1], 0), (height, width, channels))

    return jax.vmap(crop)(padded, offsets)


def random_shift(images: jax.Array, key: jax.Array, pad: int) -> jax.Array:
    """``RandomShiftsAug(pad)``: an independent integer shift in [0, 2 pad] per sample and axis
    (``torch.randint(0, 2 * pad + 1, (n, 1, 1, 2))``). ``images`` [B, H, W, C]."""
    if pad == 0:
        return images
    offsets = jax.random.randint(key, (images.shape[0], 2), 0, 2 * pad + 1)
    return shift_crop(images, offsets, pad)
