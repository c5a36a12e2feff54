"""Reconstruction (every model but DreamerPro's): decoders from the latent features to the
observation, trained by its log-likelihood.

    -ln p(x|s) = -ln N(image | ConvDecoder(s), 1) - ln N(vectors | MLPDecoder(s), 1)

summed over pixels (vector entries), averaged over batch and time. The image decoder exists
with an ``image`` key, the vector decoder (one head per key) with vector keys; the loss has
an ``image_loss`` and/or a ``vector_loss``, each with its ``<name>_mse`` metric
(:func:`gaussian_mse`).
"""

from __future__ import annotations

import dataclasses
import math

import jax
import jax.numpy as jnp

from vsgjax.agents.dreamer.networks import (
    ConvDecoder,
    MLPDecoder,
    float_to_image,
    image_to_float,
    normal_log_prob,
)
from vsgjax.agents.dreamer.representation.interface import Representation
from vsgjax.agents.precision import compute_dtype
from vsgjax.observations import IMAGE_KEY


@dataclasses.dataclass(frozen=True)
class Reconstruction(Representation):
    """The decoders ``decoder`` (image) and ``mlp_decoder`` (vector keys) and their loss."""

    decodes = True

    @property
    def decoder(self) -> ConvDecoder:
        return ConvDecoder(self.config.wm.cnn_depth, self.obs_shape.shapes[IMAGE_KEY][-1],
                           compute_dtype(self.config.precision))

    @property
    def mlp_decoder(self) -> MLPDecoder:
        spec, wm = self.obs_shape, self.config.wm
        sizes = tuple((key, spec.shapes[key][0]) for key in spec.vector_keys)
        return MLPDecoder(wm.mlp_layers, wm.mlp_units, sizes,
                          compute_dtype(self.config.precision))

    @property
    def sizes(self) -> dict[str, int]:
        """``{"image": pixel values, "vector": vector entries}`` of the decoders there are: the
        names of the ``<name>_loss`` / ``<name>_mse`` metrics."""
        spec = self.obs_shape
        sizes = {"image": math.prod(spec.shapes[IMAGE_KEY])} if spec.image_keys else {}
        if spec.vector_keys:
            sizes["vector"] = spec.vector_size
        return sizes

    def init(self, key: jax.Array, feat: jax.ShapeDtypeStruct) -> dict:
        """``{[decoder,] [mlp_decoder]}``: ``key`` initialises the image decoder,
        ``fold_in(key, 1)`` the vector one."""
        params = {}
        if self.obs_shape.image_keys:
            params["decoder"] = self.decoder.lazy_init(key, feat)["params"]
        if self.obs_shape.vector_keys:
            params["mlp_decoder"] = self.mlp_decoder.lazy_init(
                jax.random.fold_in(key, 1), feat)["params"]
        return params

    def sequence_terms(self, params: dict, embeds: jax.Array, feats: jax.Array,
                       seq: dict) -> dict:
        """``image_logp`` (summed over pixels) and/or ``vector_logp`` (summed over every
        vector key's entries), each [T]: log N(x | decoder mean, 1)."""
        terms = {}
        if self.obs_shape.image_keys:
            target = image_to_float(seq[IMAGE_KEY])
            terms["image_logp"] = normal_log_prob(self.decode(params, feats), target,
                                                  event_dims=3)
        if self.obs_shape.vector_keys:
            means = self.decode_vectors(params, feats)
            terms["vector_logp"] = sum(
                normal_log_prob(means[key], seq[key].astype(jnp.float32), event_dims=1)
                for key in self.obs_shape.vector_keys)
        return terms

    def join_losses(self, losses: dict, params: dict, batch: dict, terms: dict,
                    targets: dict | None) -> dict:
        """``<name>_loss`` = -mean log-likelihood of each decoder, before ``losses``."""
        own = {f"{name}_loss": -terms[f"{name}_logp"].mean() for name in self.sizes}
        return {**own, **losses}

    def metrics(self, losses: dict) -> dict:
        """``<name>_mse`` of each decoder (:func:`gaussian_mse`)."""
        return {f"{name}_mse": gaussian_mse(losses[f"{name}_loss"], size)
                for name, size in self.sizes.items()}

    def decode(self, params: dict, feat: jax.Array) -> jax.Array:
        """Features [..., F] -> mean image [..., 64, 64, C] in [-0.5, 0.5] units."""
        if not self.obs_shape.image_keys:
            raise ValueError(f"no image to decode: the observation spec is "
                             f"{self.obs_shape.shapes} (decode_vectors decodes vector keys)")
        return self.decoder.apply({"params": params["decoder"]}, feat)

    def decode_vectors(self, params: dict, feat: jax.Array) -> dict[str, jax.Array]:
        """Features [..., F] -> ``{vector key: mean [..., D_key]}``."""
        return self.mlp_decoder.apply({"params": params["mlp_decoder"]}, feat)

    def decode_frames(self, params: dict, feat: jax.Array, chunk: int = 256) -> jax.Array:
        """:meth:`decode` of any number of frames, ``chunk`` at a time (for viewing, not
        training): the decoder's patch matrices grow with the frames decoded at once (12,000
        imagined frames at the paper size would need ~40 GB in one go)."""
        flat = feat.reshape((-1, feat.shape[-1]))
        means = jax.lax.map(lambda f: self.decode(params, f), flat, batch_size=chunk)
        return means.reshape(feat.shape[:-1] + means.shape[1:])

    def imagined_observations(self, params: dict, feats: jax.Array) -> dict:
        """``images`` (uint8) and ``image_means`` (float, [-0.5, 0.5]) with an image,
        ``vectors`` (``{key: mean}``) with vector keys."""
        out = {}
        if self.obs_shape.image_keys:
            means = self.decode_frames(params, feats)
            out.update(images=float_to_image(means), image_means=means)
        if self.obs_shape.vector_keys:
            out["vectors"] = self.decode_vectors(params, feats)
        return out


def gaussian_mse(loss: jax.Array, size: int) -> jax.Array:
    """Mean squared error per value (pixel or vector entry) from a unit-variance Gaussian loss.

    ``loss = 0.5 * Σ err² + 0.5 * size * log(2π)``: the constant (11,291 nats for 64x64x3
    pixels) hides how much the reconstruction improves; the MSE shows it.
    """
    return (2.0 * loss - size * math.log(2.0 * math.pi)) / size
