"""Optimizers: global-norm gradient clipping followed by Adam with decoupled weight decay."""

from __future__ import annotations

import optax

from vsgjax.config import WorldModelConfig


def make_optimizer(lr: float, eps: float, clip: float,
                   weight_decay: float) -> optax.GradientTransformation:
    """clip_by_global_norm(clip) -> AdamW(lr, eps, weight_decay) (decoupled weight decay).

    Used for the world model, the actor and the critic alike.
    """
    return optax.chain(
        optax.clip_by_global_norm(clip),
        optax.adamw(lr, eps=eps, weight_decay=weight_decay),
    )


def world_model_optimizer(wm: WorldModelConfig) -> optax.GradientTransformation:
    """The world model's optimizer from its config section."""
    return make_optimizer(wm.lr, wm.eps, wm.clip, wm.weight_decay)
