"""DrQ-v2's transition, targets, losses and target update as pure functions
(facebookresearch/drqv2: ``replay_buffer.py`` ``ReplayBuffer._sample``, ``dmc.py``
``FrameStackWrapper``, ``drqv2.py`` ``DrQV2Agent.update_critic`` / ``update_actor``,
``utils.py`` ``soft_update_params``).

From a replay window to the authors' transition
-----------------------------------------------
A window holds ``history + nstep + 1`` consecutive steps of one episode (vsgjax's episode
format: step t holds the observation that ``action[t]`` led to and ``reward[t]`` that action's
reward; step 0 has zero action and reward; the replay edge-pads the ``history`` steps before the
episode's first step with it). With ``h = history``::

    obs       = frames h-S+1 .. h stacked along channels, oldest first (S = frame_stack)
    action    = action[h + 1]
    reward    = sum_{k < n} d_k reward[h + 1 + k],  d_0 = 1,
                d_{k+1} = d_k * gamma * (1 - is_terminal[h + 1 + k])
    discount  = d_n                         (the bootstrap factor)
    next_obs  = frames h+n-S+1 .. h+n stacked

The authors' ``_sample`` draws ``idx`` and returns ``observation[idx - 1]``, ``action[idx]``,
the rewards of ``idx .. idx+n-1`` weighted by the running product of ``discount[idx+i] *
gamma`` (their per-step ``discount`` is 0 at a terminal step, 1 otherwise) and
``observation[idx + n - 1]``; their observation is already the ``FrameStackWrapper`` stack
(at reset every slot holds the first frame: our edge padding). Window position ``h`` is their
``idx - 1``.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import optax


def stack_frames(images: jax.Array, last: int, count: int) -> jax.Array:
    """``images`` [B, T, H, W, C] -> [B, H, W, C * count]: frames ``last - count + 1 .. last``
    concatenated along channels, oldest first (``FrameStackWrapper._transform_observation``)."""
    frames = [images[:, last - count + 1 + i] for i in range(count)]
    return jnp.concatenate(frames, axis=-1)


def nstep_return(reward: jax.Array, is_terminal: jax.Array, first: int, nstep: int,
                 gamma: float) -> tuple[jax.Array, jax.Array]:
    """The n-step reward sum and bootstrap factor of ``ReplayBuffer._sample``, from step
    ``first`` of [B, T] ``reward`` and ``is_terminal``; each [B, 1] float32."""
    total = jnp.zeros(reward.shape[:1], jnp.float32)
    discount = jnp.ones(reward.shape[:1], jnp.float32)
    for k in range(nstep):
        total = total + discount * reward[:, first + k].astype(jnp.float32)
        discount = discount * gamma * (1.0 - is_terminal[:, first + k].astype(jnp.float32))
    return total[:, None], discount[:, None]


def transition(batch: dict, *, image_key: str | None, vector_keys: tuple[str, ...],
               frame_stack: int, history: int, nstep: int, gamma: float) -> dict:
    """A [B, history + nstep + 1, ...] window -> the authors' ``(obs, action, reward,
    discount, next_obs)`` as a dict (see the module docstring). Images: ``obs``/``next_obs``
    uint8 [B, H, W, C * frame_stack]; vectors: float32 [B, D] (vector keys concatenated)."""
    h = history
    if image_key is not None:
        obs = stack_frames(batch[image_key], h, frame_stack)
        next_obs = stack_frames(batch[image_key], h + nstep, frame_stack)
    else:
        obs = jnp.concatenate([batch[k][:, h] for k in vector_keys], -1).astype(jnp.float32)
        next_obs = jnp.concatenate([batch[k][:, h + nstep] for k in vector_keys],
                                   -1).astype(jnp.float32)
    reward, discount = nstep_return(batch["reward"], batch["is_terminal"], h + 1, nstep, gamma)
    return {"obs": obs, "action": batch["action"][:, h + 1].astype(jnp.float32),
            "reward": reward, "discount": discount, "next_obs": next_obs}


def td_target(reward: jax.Array, discount: jax.Array, target_q1: jax.Array,
              target_q2: jax.Array) -> jax.Array:
    """``reward + discount * min(Q1', Q2')`` (``update_critic``: ``target_V = torch.min``),
    with no gradient."""
    return jax.lax.stop_gradient(reward + discount * jnp.minimum(target_q1, target_q2))


def critic_loss(q1: jax.Array, q2: jax.Array, target: jax.Array) -> jax.Array:
    """``F.mse_loss(Q1, target) + F.mse_loss(Q2, target)`` (``update_critic``)."""
    return jnp.mean((q1 - target) ** 2) + jnp.mean((q2 - target) ** 2)


def actor_loss(q1: jax.Array, q2: jax.Array) -> jax.Array:
    """``-min(Q1, Q2).mean()`` (``update_actor``)."""
    return -jnp.mean(jnp.minimum(q1, q2))


def polyak(online, target, tau: float):
    """``target <- tau * online + (1 - tau) * target`` leaf by leaf (``soft_update_params``)."""
    return optax.incremental_update(online, target, tau)
