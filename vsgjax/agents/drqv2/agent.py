"""DrQ-v2 as a vsgjax agent (facebookresearch/drqv2 ``drqv2.py``: ``DrQV2Agent``).

    agent = DrQV2Agent(config, {"image": (84, 84, 3)}, action_dim=6, discrete=False)
    state = agent.init(key)                                   # DrQState pytree
    state, metrics = agent.train_step(state, batch, key)      # batch: agent.replay's windows
    carry = agent.initial_carry(num_envs)                     # the last frame_stack frames
    carry, action = agent.policy_step(agent.acting_params(state), carry, obs, key, mode="train")

One update (``DrQV2Agent.update``) on a batch of transitions (:func:`losses.transition`):

1. augment ``obs`` and ``next_obs`` with independent random shifts (pixels only);
2. encode ``obs`` (with gradient) and ``next_obs`` (without), with the encoder as it is;
3. critic: ``a' ~ actor(next_feat)`` with the schedule's std, noise clipped at ``std_clip``;
   ``y = reward + discount * min(Q1', Q2')(next_feat, a')`` with the target critic;
   ``loss = mse(Q1, y) + mse(Q2, y)``; one Adam step each for the encoder and the critic (the
   encoder learns from this loss only);
4. actor, on the detached features of step 2: ``a ~ actor(feat)`` (clipped noise),
   ``loss = -min(Q1, Q2)(feat, a).mean()`` with the critic just updated; an Adam step of the
   actor only;
5. ``critic_target <- tau * critic + (1 - tau) * critic_target``.

The std schedule reads the authors' ``global_step`` (agent steps) at the update:
``train.prefill // env.action_repeat + step * train.train_every`` (updates start when the seed
frames end and come every ``update_every_steps`` agent steps). Acting uses that of the current
state. During prefill the loop acts uniformly at random (the authors' ``num_expl_steps``: their
2000 agent steps are the 4000 seed frames).

Vector observations (MJX tasks) skip the encoder and the augmentation: the trunks read the
concatenated vector keys, with no frame stacking.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
import optax

from vsgjax.agents.drqv2 import distributions as dist
from vsgjax.agents.drqv2 import losses, schedule
from vsgjax.agents.drqv2.augment import random_shift
from vsgjax.agents.drqv2.networks import Actor, Critic, Encoder, encoder_size
from vsgjax.agents.interface import ReplayNeeds, check_mode
from vsgjax.agents.precision import compute_dtype
from vsgjax.config import Config
from vsgjax.observations import ObsSpec, obs_spec


class DrQState(NamedTuple):
    """Everything training updates (a pytree; checkpoint it whole).

    ``params``: ``{"encoder" ({} for vectors), "actor", "critic", "critic_target"}``; ``opt``:
    Adam states ``{"encoder", "actor", "critic"}``; ``step``: updates made (int32 scalar).
    """

    params: dict
    opt: dict
    step: jax.Array


@dataclass(frozen=True)
class DrQV2Agent:
    """DrQ-v2 for one observation spec (one image key, or vector keys only) and a continuous
    action space of ``action_dim`` dimensions."""

    config: Config
    obs_shape: ObsSpec | Mapping[str, Sequence[int]] | Sequence[int]
    action_dim: int
    discrete: bool

    def __post_init__(self):
        spec = obs_spec(self.obs_shape)
        object.__setattr__(self, "obs_shape", spec)
        if self.discrete:
            raise ValueError("DrQ-v2 acts in continuous action spaces only (a tanh-Gaussian "
                             "actor); got discrete=True")
        if spec.image_keys and (len(spec.image_keys) > 1 or spec.vector_keys):
            raise ValueError(f"DrQ-v2 reads one image key or vector keys only; got {spec.shapes}")

    # --- parts ---------------------------------------------------------------------------------

    @property
    def pixels(self) -> bool:
        return bool(self.obs_shape.image_keys)

    @property
    def image_key(self) -> str | None:
        return self.obs_shape.image_keys[0] if self.pixels else None

    @property
    def dtype(self):
        return compute_dtype(self.config.precision)

    @property
    def stack_shape(self) -> tuple[int, ...]:
        """A frame-stacked observation: [H, W, C * frame_stack] (pixels) or [D] (vectors)."""
        if self.pixels:
            height, width, channels = self.obs_shape.shapes[self.image_key]
            return (height, width, channels * self.config.drq.frame_stack)
        return (self.obs_shape.vector_size,)

    @property
    def repr_dim(self) -> int:
        """What the trunks read: the encoder's flat output, or the vector size."""
        if self.pixels:
            height, width, _ = self.stack_shape
            return encoder_size(height, width, self.config.drq.cnn_depth)
        return self.obs_shape.vector_size

    @functools.cached_property
    def encoder(self) -> Encoder:
        return Encoder(self.config.drq.cnn_depth, self.dtype)

    @functools.cached_property
    def actor(self) -> Actor:
        drq = self.config.drq
        return Actor(self.action_dim, drq.feature_dim, drq.hidden, self.dtype)

    @functools.cached_property
    def critic(self) -> Critic:
        return Critic(self.config.drq.feature_dim, self.config.drq.hidden, self.dtype)

    @property
    def optimizer(self) -> optax.GradientTransformation:
        """``torch.optim.Adam(lr)``: b1 0.9, b2 0.999, eps 1e-8 (eps outside the sqrt, as
        torch), no weight decay; one each for the encoder, the actor and the critic."""
        return optax.adam(self.config.drq.lr, b1=0.9, b2=0.999, eps=1e-8)

    @property
    def replay(self) -> ReplayNeeds:
        """``nstep + 1`` steps (obs, n actions and rewards, next_obs) after ``frame_stack - 1``
        steps of history for the first stack (none for vectors)."""
        drq = self.config.drq
        return ReplayNeeds(length=drq.nstep + 1,
                           history=drq.frame_stack - 1 if self.pixels else 0)

    # --- functions of parameters ----------------------------------------------------------------

    def encode(self, encoder_params: dict, obs: jax.Array) -> jax.Array:
        """Stacked uint8 frames -> ``Encoder`` features; vectors pass through as float32."""
        if self.pixels:
            return self.encoder.apply({"params": encoder_params}, obs)
        return obs.astype(jnp.float32)

    def mean_action(self, actor_params: dict, feat: jax.Array) -> jax.Array:
        return self.actor.apply({"params": actor_params}, feat)

    def q_values(self, critic_params: dict, feat: jax.Array, action: jax.Array):
        return self.critic.apply({"params": critic_params}, feat, action)

    def std(self, step: jax.Array | int) -> jax.Array:
        """The exploration std after ``step`` updates: ``utils.schedule`` at the authors'
        ``global_step`` = ``prefill // action_repeat + step * train_every`` agent steps."""
        train, drq = self.config.train, self.config.drq
        agent_step = (train.prefill // self.config.env.action_repeat
                      + jnp.asarray(step, jnp.int32) * train.train_every)
        return schedule.linear(agent_step, drq.std_start, drq.std_end, drq.std_steps)

    def transition(self, batch: dict) -> dict:
        """The authors' ``(obs, action, reward, discount, next_obs)`` from a replay window."""
        drq, needs = self.config.drq, self.replay
        length = next(iter(batch[k] for k in self.obs_shape.keys)).shape[1]
        if length != needs.history + needs.length:
            raise ValueError(f"DrQ-v2 wants windows of {needs.history + needs.length} steps "
                             f"(history {needs.history} + nstep + 1 = {needs.length}); got "
                             f"{length}")
        return losses.transition(batch, image_key=self.image_key,
                                 vector_keys=self.obs_shape.vector_keys,
                                 frame_stack=drq.frame_stack, history=needs.history,
                                 nstep=drq.nstep, gamma=drq.gamma)

    def target_q(self, params: dict, next_feat: jax.Array, reward: jax.Array,
                 discount: jax.Array, std: jax.Array, key: jax.Array) -> jax.Array:
        """``update_critic``'s target: ``reward + discount * min(Q1', Q2')(next_feat, a')``,
        ``a' ~ TruncatedNormal(actor(next_feat), std).sample(clip=std_clip)``, target critic."""
        next_feat = jax.lax.stop_gradient(next_feat)
        mean = self.mean_action(params["actor"], next_feat)
        next_action = dist.sample(key, mean, std, self.config.drq.std_clip)
        q1, q2 = self.q_values(params["critic_target"], next_feat, next_action)
        return losses.td_target(reward, discount, q1, q2)

    def critic_objective(self, params: dict, obs: jax.Array, action: jax.Array,
                         target: jax.Array):
        """``update_critic``'s loss of the encoder and critic parameters in ``params`` (the
        target is a constant) -> ``(loss, (feat, q1, q2))``."""
        feat = self.encode(params["encoder"], obs)
        q1, q2 = self.q_values(params["critic"], feat, action)
        return losses.critic_loss(q1, q2, jax.lax.stop_gradient(target)), (feat, q1, q2)

    def actor_objective(self, params: dict, feat: jax.Array, std: jax.Array, key: jax.Array):
        """``update_actor``'s loss: of the actor parameters only (the features are detached,
        as ``obs.detach()``, and the critic is read, not trained) -> ``(loss, metrics)``."""
        feat = jax.lax.stop_gradient(feat)
        critic = jax.lax.stop_gradient(params["critic"])
        mean = self.mean_action(params["actor"], feat)
        action = dist.sample(key, mean, std, self.config.drq.std_clip)
        q1, q2 = self.q_values(critic, feat, action)
        loss = losses.actor_loss(q1, q2)
        action = jax.lax.stop_gradient(action)
        metrics = {"actor/logprob": jnp.mean(jnp.sum(dist.log_prob(action, mean, std), -1)),
                   "actor/entropy": jnp.mean(jnp.sum(dist.entropy(mean, std), -1))}
        return loss, jax.lax.stop_gradient(metrics)

    # --- the interface ----------------------------------------------------------------------------

    @functools.partial(jax.jit, static_argnums=0)
    def init(self, key: jax.Array) -> DrQState:
        """Orthogonal weights, zero biases (``utils.weight_init``), the target critic a copy of
        the critic, fresh Adam states, step 0."""
        encoder_key, actor_key, critic_key = jax.random.split(key, 3)
        if self.pixels:
            dummy = jnp.zeros((1,) + self.stack_shape, jnp.uint8)
            encoder = self.encoder.init(encoder_key, dummy)["params"]
        else:
            encoder = {}
        feat = jnp.zeros((1, self.repr_dim), jnp.float32)
        actor = self.actor.init(actor_key, feat)["params"]
        critic = self.critic.init(critic_key, feat,
                                  jnp.zeros((1, self.action_dim), jnp.float32))["params"]
        params = {"encoder": encoder, "actor": actor, "critic": critic,
                  "critic_target": jax.tree.map(jnp.array, critic)}
        opt = {name: self.optimizer.init(params[name]) for name in ("encoder", "actor", "critic")}
        return DrQState(params, opt, jnp.zeros((), jnp.int32))

    @functools.partial(jax.jit, static_argnums=0)
    def train_step(self, state: DrQState, batch: dict, key: jax.Array):
        """One ``DrQV2Agent.update`` (see the module docstring) -> ``(state, metrics)`` with
        ``critic/*``, ``actor/*`` and ``data/batch_reward``."""
        aug_key, next_aug_key, target_key, actor_key = jax.random.split(key, 4)
        params, opt = state.params, dict(state.opt)
        batch = self.transition(batch)
        obs, next_obs = batch["obs"], batch["next_obs"]
        if self.pixels:
            pad = self.config.drq.shift_pad
            obs, next_obs = random_shift(obs, aug_key, pad), random_shift(next_obs,
                                                                           next_aug_key, pad)
        std = self.std(state.step)
        next_feat = jax.lax.stop_gradient(self.encode(params["encoder"], next_obs))
        target = self.target_q(params, next_feat, batch["reward"], batch["discount"], std,
                               target_key)

        def critic_fn(trained):
            return self.critic_objective({**params, **trained}, obs, batch["action"], target)

        trained = {"encoder": params["encoder"], "critic": params["critic"]}
        (critic_loss, (feat, q1, q2)), grads = jax.value_and_grad(critic_fn, has_aux=True)(
            trained)
        encoder, opt["encoder"] = _apply(self.optimizer, grads["encoder"], opt["encoder"],
                                         params["encoder"])
        critic, opt["critic"] = _apply(self.optimizer, grads["critic"], opt["critic"],
                                       params["critic"])

        def actor_fn(actor):
            return self.actor_objective({**params, "actor": actor, "critic": critic}, feat, std,
                                        actor_key)

        (actor_loss, actor_metrics), actor_grads = jax.value_and_grad(actor_fn, has_aux=True)(
            params["actor"])
        actor, opt["actor"] = _apply(self.optimizer, actor_grads, opt["actor"], params["actor"])
        critic_target = losses.polyak(critic, params["critic_target"], self.config.drq.tau)

        metrics = {"critic/loss": critic_loss, "critic/q1": jnp.mean(q1),
                   "critic/q2": jnp.mean(q2), "critic/target_q": jnp.mean(target),
                   "actor/loss": actor_loss, **actor_metrics, "actor/std": std,
                   "data/batch_reward": jnp.mean(batch["reward"])}
        metrics = {name: jnp.asarray(value, jnp.float32) for name, value in metrics.items()}
        new_params = {"encoder": encoder, "actor": actor, "critic": critic,
                      "critic_target": critic_target}
        return DrQState(new_params, opt, state.step + 1), metrics

    def acting_params(self, state: DrQState) -> dict:
        """``{"encoder", "actor", "std"}``: ``std`` the schedule's after ``state.step``
        updates (float32 scalar)."""
        return {"encoder": state.params["encoder"], "actor": state.params["actor"],
                "std": self.std(state.step)}

    def initial_carry(self, num_envs: int) -> jax.Array:
        """The frame stack ``[N, H, W, C * frame_stack]`` uint8 (refilled at ``is_first``), or
        an empty ``[N, 0]`` placeholder for vectors."""
        if self.pixels:
            return jnp.zeros((num_envs,) + self.stack_shape, jnp.uint8)
        return jnp.zeros((num_envs, 0), jnp.float32)

    @functools.partial(jax.jit, static_argnums=0, static_argnames="mode")
    def policy_step(self, params: dict, carry: jax.Array, obs: dict, key: jax.Array, *,
                    mode: str = "train") -> tuple[jax.Array, jax.Array]:
        """``DrQV2Agent.act`` for N environments.

        Pixels: the newest frame joins the stack, the oldest leaves (``FrameStackWrapper.step``);
        where ``is_first``, every slot takes the current frame (``FrameStackWrapper.reset``).
        ``"eval"``: the actor's mean; ``"train"``: a sample with the schedule's std and no noise
        clip (``dist.sample(clip=None)``), clamped inside (-1, 1). float32 [N, A].
        """
        check_mode(mode)
        if self.pixels:
            frame = obs[self.image_key]
            channels = frame.shape[-1]
            stepped = jnp.concatenate([carry[..., channels:], frame.astype(carry.dtype)], -1)
            fresh = jnp.tile(frame.astype(carry.dtype), (1, 1, 1, self.config.drq.frame_stack))
            first = jnp.asarray(obs["is_first"], bool)[:, None, None, None]
            carry = jnp.where(first, fresh, stepped)
            x = carry
        else:
            x = jnp.concatenate([obs[k] for k in self.obs_shape.vector_keys], -1)
        mean = self.mean_action(params["actor"], self.encode(params["encoder"], x))
        if mode == "eval":
            action = mean
        else:
            action = dist.sample(key, mean, params["std"], clip=None)
        return carry, jax.lax.stop_gradient(action).astype(jnp.float32)


def _apply(optimizer: optax.GradientTransformation, grads, opt_state, params):
    """One optimizer step -> (new params, new optimizer state)."""
    updates, opt_state = optimizer.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state
