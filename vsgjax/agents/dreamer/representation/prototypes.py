"""DreamerPro's prototypes (the DreamerPro and VSGPro models): no decoder; ``-ln p(x|s)`` is
replaced by the prototype losses of :mod:`.prototype_losses`, computed over the whole batch
of two augmented views, with targets from an EMA copy of the encoder and its projection.

Parameters ``proto = {prototypes [K, D] ~ N(0, 1), obs_proj, feat_proj}`` (the release's
RSSM and its ``proto_loss`` layers; ``obs_proj`` / ``feat_proj`` one linear layer each to
``proto.dim``, of the embedding and of the features); EMA targets ``{encoder, obs_proj}``.
Each update the prototypes are L2-normalised (the release assigns them normalised before
every loss) and their gradient zeroed for the first ``proto.freeze_updates`` updates.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from vsgjax.agents.dreamer.networks import MLP, ConvEncoder, image_to_float
from vsgjax.agents.dreamer.representation import prototype_losses as losses_of
from vsgjax.agents.dreamer.representation.interface import Representation
from vsgjax.agents.precision import compute_dtype
from vsgjax.observations import IMAGE_KEY

sg = jax.lax.stop_gradient


@dataclasses.dataclass(frozen=True)
class Prototypes(Representation):
    """Prototypes, projections and EMA targets of the image alone."""

    def __post_init__(self):
        spec = self.obs_shape
        if spec.vector_keys or not spec.image_keys:
            raise ValueError(f"model {self.model!r} learns from prototypes of the image "
                             f"alone; the observation spec is {spec.shapes}")

    @property
    def encoder(self) -> ConvEncoder:
        """The world model's image encoder, of which the targets keep an EMA copy."""
        return ConvEncoder(self.config.wm.cnn_depth, compute_dtype(self.config.precision))

    @property
    def projection(self) -> MLP:
        """DreamerPro's ``obs_proj`` / ``feat_proj``: one linear layer to ``proto.dim``."""
        return MLP(0, 1, (self.config.proto.dim,), dtype=compute_dtype(self.config.precision))

    def init(self, key: jax.Array, feat: jax.ShapeDtypeStruct) -> dict:
        """``{proto: {prototypes, obs_proj, feat_proj}}`` from the three splits of ``key``."""
        k_proto, k_obs, k_feat = jax.random.split(key, 3)
        proto = self.config.proto
        embed = jax.ShapeDtypeStruct((self.embed_size,), jnp.float32)
        return {"proto": {"prototypes": jax.random.normal(k_proto, (proto.prototypes, proto.dim)),
                          "obs_proj": self.projection.lazy_init(k_obs, embed)["params"],
                          "feat_proj": self.projection.lazy_init(k_feat, feat)["params"]}}

    def init_targets(self, key: jax.Array) -> dict:
        """The EMA target networks ``{encoder, obs_proj}``, initialised on their own (the
        release's ``_ema_encoder``, ``_ema_obs_proj``; its first update copies the online
        networks into them: :meth:`update_targets`)."""
        k_enc, k_proj = jax.random.split(key)
        image = jax.ShapeDtypeStruct(self.obs_shape.shapes[IMAGE_KEY], jnp.float32)
        embed = jax.ShapeDtypeStruct((self.embed_size,), jnp.float32)
        return {"encoder": self.encoder.lazy_init(k_enc, image)["params"],
                "obs_proj": self.projection.lazy_init(k_proj, embed)["params"]}

    def update_targets(self, params: dict, targets: dict, step: jax.Array) -> dict:
        """An EMA of the online encoder and ``obs_proj`` with ``proto.ema_fraction``, a copy
        after the first update."""
        online = {"encoder": params["encoder"], "obs_proj": params["proto"]["obs_proj"]}
        return losses_of.ema_update(online, targets, self.config.proto.ema_fraction, step == 0)

    def training_views(self, params: dict, batch: dict, key: jax.Array) -> tuple[dict, dict]:
        """The prototypes L2-normalised, and the batch as two augmented views ``[2B, T]``."""
        proto = dict(params["proto"], prototypes=losses_of.l2_normalize(
            params["proto"]["prototypes"]))
        floats = dict(batch, **{IMAGE_KEY: image_to_float(batch[IMAGE_KEY])})
        return dict(params, proto=proto), losses_of.two_views(floats, key,
                                                              self.config.proto.shift)

    def mask_gradients(self, grads: dict, step: jax.Array) -> dict:
        """The prototypes' gradient zeroed for the first ``proto.freeze_updates`` updates."""
        frozen = step < self.config.proto.freeze_updates
        proto = dict(grads["proto"], prototypes=losses_of.freeze(grads["proto"]["prototypes"],
                                                                 frozen))
        return dict(grads, proto=proto)

    def sequence_terms(self, params: dict, embeds: jax.Array, feats: jax.Array,
                       seq: dict) -> dict:
        """The raw projections ``obs_proj`` (of the embedding) and ``feat_proj`` (of the
        features), [T, D], for the batch-wide prototype losses."""
        project = lambda name, x: self.projection.apply({"params": params["proto"][name]}, x)
        return {"obs_proj": project("obs_proj", embeds), "feat_proj": project("feat_proj", feats)}

    def join_losses(self, losses: dict, params: dict, batch: dict, terms: dict,
                    targets: dict | None) -> dict:
        """``losses``, then ``swav_loss``, ``temp_loss``, ``norm_loss`` (scaled) of the batch's
        two views: the targets' projections (L2-normalised, no gradient) scored against the
        prototypes."""
        if targets is None:
            raise ValueError(f"model {self.model!r} learns from prototypes: its loss needs "
                             f"the EMA target networks (init_targets); train it through "
                             f"vsgjax.agents.make_agent")
        proto = self.config.proto
        embed = self.encoder.apply({"params": targets["encoder"]}, batch[IMAGE_KEY])
        ema_proj = losses_of.l2_normalize(
            self.projection.apply({"params": targets["obs_proj"]}, embed).astype(jnp.float32))
        raw = losses_of.prototype_losses(
            params["proto"]["prototypes"], terms["obs_proj"], terms["feat_proj"], sg(ema_proj),
            temperature=proto.temperature, sinkhorn_eps=proto.sinkhorn_eps,
            sinkhorn_iters=proto.sinkhorn_iters, warm_up=proto.warm_up)
        scales = {"swav": proto.swav_scale, "temp": proto.temp_scale, "norm": proto.norm_scale}
        return {**losses, **{f"{name}_loss": scales[name] * value for name, value in raw.items()}}
