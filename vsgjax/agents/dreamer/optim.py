"""Optimizers: global-norm clipping, Adam, weight decay, as the authors' release (TF2) does them.

One rule for the world model, the actor and the critic (``optim.*`` picks the rule, the
sections ``wm.*`` / ``ac.*`` give the rates)::

    g  <- clip_by_global_norm(g, clip)
    Δ  <- -lr · adam(g)                  eps placement: optim.eps_placement
    θ  <- (1 - wd) · (θ + Δ)             optim.weight_decay=release (the default)
    θ  <- θ + Δ - lr · wd · θ            optim.weight_decay=adamw (optax.adamw's decoupled decay)

Adam's epsilon: TensorFlow's Adam (the release) computes
``lr · sqrt(1 - β2^t) / (1 - β1^t) · m / (sqrt(v) + ε)``, i.e. ε is added to sqrt(v), not to
the bias-corrected sqrt(v̂) as in optax: the same as optax's rule with ε_t = ε / sqrt(1 - β2^t),
a ~32x larger ε at the first step that falls to ε as t grows (``eps_placement=release``).
The release's decay is not scaled by the learning rate: with wd = 1e-6 over 125k updates it
shrinks every variable (kernels and biases) by a factor 0.882, where AdamW's ``lr · wd`` would
shrink them by 0.99999.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax

from vsgjax.agents.dreamer.settings import EPS_PLACEMENTS, WEIGHT_DECAYS, OptimConfig
from vsgjax.config import Config

ADAM_B1, ADAM_B2 = 0.9, 0.999  # TF's and optax's defaults; the release sets neither


def scale_by_tf_adam(b1: float = ADAM_B1, b2: float = ADAM_B2,
                     eps: float = 1e-5) -> optax.GradientTransformation:
    """Adam's direction with TensorFlow's epsilon placement (see the module docstring).

    Keeps optax's :class:`optax.ScaleByAdamState`, so the state has the same structure as
    :func:`optax.scale_by_adam`'s.
    """

    def init(params):
        return optax.ScaleByAdamState(count=jnp.zeros([], jnp.int32),
                                      mu=optax.tree.zeros_like(params),
                                      nu=optax.tree.zeros_like(params))

    def update(updates, state, params=None):
        del params
        mu = optax.tree.update_moment(updates, state.mu, b1, 1)
        nu = optax.tree.update_moment_per_elem_norm(updates, state.nu, b2, 2)
        count = optax.safe_increment(state.count)
        t = count.astype(jnp.float32)
        step = jnp.sqrt(1.0 - b2 ** t) / (1.0 - b1 ** t)
        updates = jax.tree.map(lambda m, v: step * m / (jnp.sqrt(v) + eps), mu, nu)
        return updates, optax.ScaleByAdamState(count=count, mu=mu, nu=nu)

    return optax.GradientTransformation(init, update)


def release_weight_decay(weight_decay: float) -> optax.GradientTransformation:
    """θ <- (1 - wd)·(θ + Δ) after the step Δ: Δ becomes (1 - wd)·Δ - wd·θ (optax blocks)."""
    return optax.chain(optax.scale(1.0 - weight_decay), optax.add_decayed_weights(-weight_decay))


RELEASE_RULE = OptimConfig()


def make_optimizer(lr: float, eps: float, clip: float, weight_decay: float,
                   rule: OptimConfig = RELEASE_RULE) -> optax.GradientTransformation:
    """clip -> Adam (``rule.eps_placement``) -> lr -> weight decay (``rule.weight_decay``)."""
    if rule.eps_placement not in EPS_PLACEMENTS:
        raise ValueError(f"unknown optim.eps_placement {rule.eps_placement!r}; "
                         f"valid: {', '.join(EPS_PLACEMENTS)}")
    if rule.weight_decay not in WEIGHT_DECAYS:
        raise ValueError(f"unknown optim.weight_decay {rule.weight_decay!r}; "
                         f"valid: {', '.join(WEIGHT_DECAYS)}")
    adam = (scale_by_tf_adam(eps=eps) if rule.eps_placement == "release"
            else optax.scale_by_adam(ADAM_B1, ADAM_B2, eps=eps))
    if rule.weight_decay == "adamw":
        return optax.chain(optax.clip_by_global_norm(clip), adam,
                           optax.add_decayed_weights(weight_decay),
                           optax.scale_by_learning_rate(lr))
    return optax.chain(optax.clip_by_global_norm(clip), adam, optax.scale_by_learning_rate(lr),
                       release_weight_decay(weight_decay))


def world_model_optimizer(config: Config) -> optax.GradientTransformation:
    """The world model's optimizer: rates from ``wm.*``, the rule from ``optim.*``."""
    wm = config.wm
    return make_optimizer(wm.lr, wm.eps, wm.clip, wm.weight_decay, config.optim)


def agent_optimizers(config: Config) -> dict[str, optax.GradientTransformation]:
    """``{"wm", "actor", "critic"}`` optimizers (actor and critic rates from ``ac.*``)."""
    ac = config.ac
    return {"wm": world_model_optimizer(config),
            **{name: make_optimizer(lr, ac.eps, ac.clip, ac.weight_decay, config.optim)
               for name, lr in (("actor", ac.actor_lr), ("critic", ac.critic_lr))}}
