"""The interface of the world model's representation component
(:mod:`vsgjax.agents.dreamer.representation`)."""

from __future__ import annotations

import dataclasses

import jax

from vsgjax.config import Config
from vsgjax.observations import ObsSpec


@dataclasses.dataclass(frozen=True)
class Representation:
    """The interface; the defaults are those of a representation without EMA targets, batch
    views, gradient masks or decoders.

    ``model``: the agent's name (for messages); ``embed_size``: the size of the world model's
    embedding. Parameter arguments are the world model's whole params dict.
    """

    config: Config
    obs_shape: ObsSpec
    embed_size: int
    model: str

    decodes = False  # whether states decode to observations

    def init(self, key: jax.Array, feat: jax.ShapeDtypeStruct) -> dict:
        """This representation's entries of the world model's params."""
        raise NotImplementedError

    def init_targets(self, key: jax.Array) -> dict | None:
        """Fresh EMA target networks (the agent keeps them as ``wm_targets``), or None."""
        return None

    def update_targets(self, params: dict, targets: dict, step: jax.Array) -> dict:
        """The targets after update ``step``."""
        return targets

    def training_views(self, params: dict, batch: dict, key: jax.Array) -> tuple[dict, dict]:
        """What one update trains on: ``(params, batch)``."""
        return params, batch

    def mask_gradients(self, grads: dict, step: jax.Array) -> dict:
        """The world model's gradient of update ``step`` as the optimizer applies it."""
        return grads

    def sequence_terms(self, params: dict, embeds: jax.Array, feats: jax.Array,
                       seq: dict) -> dict:
        """Per-step terms [T, ...] of ONE sequence (embeddings and posterior features)."""
        raise NotImplementedError

    def join_losses(self, losses: dict, params: dict, batch: dict, terms: dict,
                    targets: dict | None) -> dict:
        """The world model's ``losses`` (reward, KL, discount) joined with this
        representation's, from the batch-wide ``terms`` [B, T]; the order is the order of
        summation."""
        raise NotImplementedError

    def metrics(self, losses: dict) -> dict:
        """Metrics derived from the losses."""
        return {}

    def decode(self, params: dict, feat: jax.Array) -> jax.Array:
        """Features [..., F] -> mean image [..., 64, 64, C]."""
        raise ValueError(f"model {self.model!r} has no decoder: its states cannot be drawn "
                         f"as images")

    def imagined_observations(self, params: dict, feats: jax.Array) -> dict:
        """The observations decoded from imagined features [N, H, F] (none here)."""
        return {}
