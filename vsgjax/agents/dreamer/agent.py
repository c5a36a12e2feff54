"""The Dreamer-family agent (every model of :func:`vsgjax.registry.agents.dreamer_models`): one
jitted update of world model, actor and critic, and jitted acting; it implements
:mod:`vsgjax.agents.interface`.

    agent = DreamerAgent(config, obs_shape=(64, 64, 3), action_dim=2, discrete=False)
    # or obs_shape={"vector": (24,)} (an ObsSpec or {key: shape}; see vsgjax.observations)
    state = agent.init(key)                                   # AgentState pytree
    state, metrics = agent.train_step(state, batch, key)      # batch: the [B, T] sequence dict
    carry = agent.initial_carry(num_envs)
    carry, action = agent.policy_step(agent.acting_params(state), carry, obs, key, mode="train")

``DreamerAgent`` is a frozen dataclass of hashable fields, so its methods are jitted with
``self`` as a
static argument: equal agents share compiled code. Behaviour learning is in
:mod:`vsgjax.agents.dreamer.behaviour` (with the timestep-alignment diagram).
"""

from __future__ import annotations

import functools
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax

from vsgjax.agents.dreamer import behaviour as bhv
from vsgjax.agents.dreamer.gate_statistics import gate_statistics
from vsgjax.agents.dreamer.open_loop import open_loop_video, shortened_open_loop_errors
from vsgjax.agents.dreamer.optim import agent_optimizers
from vsgjax.agents.dreamer.world_model import WorldModel
from vsgjax.agents.interface import ReplayNeeds, check_mode
from vsgjax.config import Config
from vsgjax.observations import ObsSpec, obs_spec


class AgentState(NamedTuple):
    """Everything training updates (a pytree; checkpoint it whole).

    ``params``: ``{"wm", "actor", "critic", "slow_critic"}`` (and ``"wm_targets"``, the EMA
    target networks of a representation that has them, DreamerPro's prototypes); ``opt``:
    optimizer states ``{"wm", "actor", "critic"}``; ``step``: number of completed updates
    (int32 scalar).
    """

    params: dict
    opt: dict
    step: jax.Array


Carry = tuple[Any, jax.Array]  # (posterior states [N, ...], previous actions [N, A])


@dataclass(frozen=True)
class DreamerAgent:
    """World model + imagination actor-critic for one observation spec and action space.

    ``obs_shape``: an image shape ``(64, 64, C)``, a ``{key: shape}`` dict or an
    :class:`~vsgjax.observations.ObsSpec`; stored as the ObsSpec.
    """

    config: Config
    obs_shape: ObsSpec | Mapping[str, Sequence[int]] | Sequence[int]
    action_dim: int
    discrete: bool

    def __post_init__(self):
        object.__setattr__(self, "obs_shape", obs_spec(self.obs_shape))

    @property
    def replay(self) -> ReplayNeeds:
        """Sequences of ``train.length`` steps."""
        return ReplayNeeds(self.config.train.length)

    def acting_params(self, state: AgentState) -> dict:
        """Acting reads every network (the encoder and dynamics for the posterior, the actor)."""
        return state.params

    @functools.cached_property
    def world_model(self) -> WorldModel:
        return WorldModel(self.config, self.obs_shape, self.action_dim)

    @property
    def behaviour(self) -> bhv.Behaviour:
        return bhv.Behaviour.from_config(self.config, self.action_dim, self.discrete)

    @property
    def optimizers(self) -> dict[str, optax.GradientTransformation]:
        return agent_optimizers(self.config)

    @functools.partial(jax.jit, static_argnums=0)
    def init(self, key: jax.Array) -> AgentState:
        """Fresh parameters (the slow critic a copy of the critic), optimizer states, step 0.

        Jitted: one compiled program instead of hundreds of op-by-op initialisers.
        """
        wm_key, ac_key = jax.random.split(key)
        params = {"wm": self.world_model.init(wm_key),
                  **self.behaviour.init(ac_key, self.world_model.dynamics.feat_dim)}
        targets = self.world_model.representation.init_targets(jax.random.fold_in(key, 1))
        if targets is not None:
            params["wm_targets"] = targets
        opt = {name: optimizer.init(params[name]) for name, optimizer in self.optimizers.items()}
        return AgentState(params, opt, jnp.zeros((), jnp.int32))

    # --- training ------------------------------------------------------------------------------

    def world_fns(self, wm_params: dict) -> bhv.WorldFns:
        """The world-model callables behaviour learning imagines with (per start state)."""
        wm = self.world_model
        dyn = wm.dynamics

        def rollout(policy, start, key, steps):
            states, actions = dyn.imagine(wm_params["dynamics"], policy, start, steps, key)
            return jax.vmap(dyn.feat)(states), actions

        return bhv.WorldFns(rollout=rollout,
                            reward=lambda feat: wm.reward_mean(wm_params, feat),
                            discount=lambda feat: wm.discount(wm_params, feat))

    @functools.partial(jax.jit, static_argnums=0)
    def train_step(self, state: AgentState, batch: dict, key: jax.Array):
        """One update of world model, then actor, then critic, with the slow-critic schedule.

        The world model trains on ``batch``; its posterior states (stop-gradient; see
        :func:`vsgjax.agents.dreamer.behaviour.start_states` for which; ``ac.starts`` of them
        when it is
        not 0) start the imagination, which uses the freshly updated world model. The slow
        critic is copied from the critic at the start of the update (``ac.alignment=release``)
        or after it (``next_state``). The world model's representation component decides what
        world model and actor-critic train on (a prototype model: two augmented views of the
        batch), masks the world model's gradient (the prototypes' frozen for the first
        updates), and moves its EMA targets, if any, after the world-model step. Returns
        ``(state, metrics)`` with keys ``wm/*``, ``actor/*``, ``critic/*`` and ``imag/*``.
        """
        wm_key, ac_key = jax.random.split(key)
        params, opt, optimizers = dict(state.params), dict(state.opt), self.optimizers
        behaviour, every, wm = self.behaviour, self.config.ac.slow_critic_every, self.world_model
        rep = wm.representation
        wm_params, batch = rep.training_views(params["wm"], batch, jax.random.fold_in(key, 1))
        grad_fn = jax.value_and_grad(wm.loss, has_aux=True)
        (_, (wm_metrics, posts)), grads = grad_fn(wm_params, batch, wm_key,
                                                  params.get("wm_targets"))
        grads = rep.mask_gradients(grads, state.step)
        wm_params, opt["wm"] = _apply(optimizers["wm"], grads, opt["wm"], wm_params)
        if "wm_targets" in params:
            params["wm_targets"] = rep.update_targets(wm_params, params["wm_targets"], state.step)

        slow_critic = params["slow_critic"]
        if behaviour.release:
            slow_critic = bhv.update_slow_critic(params["critic"], slow_critic, state.step, every)
        if self.config.ac.memoryless_starts:
            posts = self._posteriors_alone(wm_params, batch, jax.random.fold_in(key, 2))
        starts, start_continue = bhv.start_states(posts, batch["is_terminal"], behaviour,
                                                  drop_last=self.config.wm.discount_head)
        if self.config.ac.starts:
            ac_key, draw_key = jax.random.split(ac_key)
            starts, start_continue = bhv.draw_starts(starts, start_continue,
                                                     self.config.ac.starts, draw_key)
        keys = jax.random.split(ac_key, start_continue.shape[0])
        grad_fn = jax.value_and_grad(bhv.actor_loss, has_aux=True)
        (_, (imagined, ac_metrics)), actor_grads = grad_fn(
            params["actor"], behaviour, params["critic"], slow_critic,
            self.world_fns(wm_params), starts, start_continue, keys)
        actor, opt["actor"] = _apply(optimizers["actor"], actor_grads, opt["actor"],
                                     params["actor"])

        grad_fn = jax.value_and_grad(bhv.critic_loss, has_aux=True)
        (_, critic_metrics), critic_grads = grad_fn(params["critic"], behaviour, imagined)
        critic, opt["critic"] = _apply(optimizers["critic"], critic_grads, opt["critic"],
                                       params["critic"])
        if not behaviour.release:
            slow_critic = bhv.update_slow_critic(critic, slow_critic, state.step, every)

        metrics = {f"wm/{name}": value for name, value in wm_metrics.items()}
        metrics.update(ac_metrics, **critic_metrics)
        metrics.update({"wm/grad_norm": optax.tree.norm(grads),
                        "actor/grad_norm": optax.tree.norm(actor_grads),
                        "critic/grad_norm": optax.tree.norm(critic_grads)})
        new_params = dict(params, wm=wm_params, actor=actor, critic=critic,
                          slow_critic=slow_critic)
        return AgentState(new_params, opt, state.step + 1), metrics

    def _posteriors_alone(self, wm_params: dict, batch: dict, key: jax.Array):
        """:func:`posteriors_alone` of every step of the [B, T] batch (the memoryless
        control's imagination starts)."""
        dyn, embeds = self.world_model.dynamics, self.world_model.encode(wm_params, batch)
        keys = jax.random.split(key, embeds.shape[0])
        return jax.vmap(lambda e, k: posteriors_alone(dyn, wm_params["dynamics"], e,
                                                      self.action_dim, k))(embeds, keys)

    # --- analysis ------------------------------------------------------------------------------

    @property
    def gated(self) -> bool:
        """Whether the latent states carry update gates (VSG, SVSG)."""
        return self.world_model.dynamics.gated

    def gate_summary(self, state: AgentState, batch: dict, memory_gap: int = 0
                     ) -> dict[str, float]:
        """The ``gates/*`` scalars of the state's world model on a ``[B, T]`` batch (with
        ``gates/holding_<memory_gap>`` and ``gates/written_and_held_<memory_gap>`` for a task
        that names its memory gap)."""
        stats = gate_statistics(state.params["wm"], batch, config=self.config)
        return stats.summary(memory_gap=memory_gap)

    def open_loop_video(self, state: AgentState, episode: dict, key: jax.Array):
        """The run's open-loop prediction video of an episode (uint8 frames), or None for an
        episode without images (:mod:`vsgjax.agents.dreamer.open_loop`)."""
        return open_loop_video(self.config, state.params["wm"], episode, key)

    def open_loop_errors(self, state: AgentState, episodes: dict, key: jax.Array):
        """The world model's open-loop prediction errors on a batch of episodes ``[N, T]``:
        ``{"obs_mse": [H], "reward_mse": [H]}`` per imagined step after 15 observed ones, H =
        35 (fewer for episodes shorter than 50 steps), or None below 4 steps (jittable;
        :func:`vsgjax.agents.dreamer.open_loop.open_loop_errors`)."""
        return shortened_open_loop_errors(self.config, state.params["wm"], episodes, key)

    # --- acting --------------------------------------------------------------------------------

    def initial_carry(self, num_envs: int) -> Carry:
        """Zero posterior states and zero previous actions for ``num_envs`` environments."""
        zeros = lambda x: jnp.zeros((num_envs,) + x.shape, x.dtype)
        return (jax.tree.map(zeros, self.world_model.dynamics.initial()),
                jnp.zeros((num_envs, self.action_dim), jnp.float32))

    @functools.partial(jax.jit, static_argnums=0, static_argnames="mode")
    def policy_step(self, params: dict, carry: Carry, obs: dict, key: jax.Array, *,
                    mode: str = "train") -> tuple[Carry, jax.Array]:
        """One acting step for a batch of N environments.

        ``obs``: the spec's keys (``image`` [N, H, W, C] uint8, vectors [N, D] float32) and
        ``is_first`` [N] bool (other keys ignored).
        Where ``is_first``, the carried state and previous action are zeroed before the
        posterior step. With ``ac.memoryless`` (`cpu_memory`'s control) every step is
        treated as ``is_first``: the posterior is the observation's alone, nothing is carried
        between steps (training is unchanged). ``mode="train"`` samples the actor, ``"eval"``
        takes its mode (the latent state and VSG's gates are sampled in both, as in the
        released code). Actions are float32 [N, A]: in [-1, 1] when continuous, one-hot when
        discrete. Returns ``((posts, action), action)``.
        """
        check_mode(mode)
        dyn, states, prev_actions = self.world_model.dynamics, *carry
        state_key, action_key = jax.random.split(key)
        embeds = self.world_model.encode(params["wm"], obs)

        def posterior(state, action, is_first, embed, step_key):
            state, action = dyn.reset(state, action, is_first)
            return dyn.obs_step(params["wm"]["dynamics"], state, action, embed, step_key)[0]

        if self.config.ac.memoryless:
            posts = posteriors_alone(dyn, params["wm"]["dynamics"], embeds, self.action_dim,
                                     state_key)
        else:
            keys = jax.random.split(state_key, embeds.shape[0])
            posts = jax.vmap(posterior)(states, prev_actions, obs["is_first"], embeds, keys)
        action = self.behaviour.act(params["actor"], jax.vmap(dyn.feat)(posts), action_key, mode)
        action = jax.lax.stop_gradient(action)
        return (posts, action), action


def posteriors_alone(dynamics, dyn_params: dict, embeds: jax.Array, action_dim: int,
                     key: jax.Array):
    """The posterior of each embedding [N, E] alone: one posterior step from the all-zero
    initial state and a zero previous action, as at an episode's first step. The memoryless
    control acts from these (``ac.memoryless``) and, with ``ac.memoryless_starts``, imagines
    from them."""
    initial = jax.tree.map(lambda x: jnp.broadcast_to(x, (embeds.shape[0],) + x.shape),
                           dynamics.initial())
    no_action = jnp.zeros(action_dim, jnp.float32)

    def posterior(state, embed, step_key):
        return dynamics.obs_step(dyn_params, state, no_action, embed, step_key)[0]

    return jax.vmap(posterior)(initial, embeds, jax.random.split(key, embeds.shape[0]))


def _apply(optimizer: optax.GradientTransformation, grads, opt_state, params):
    """One optimizer step -> (new params, new optimizer state)."""
    updates, opt_state = optimizer.update(grads, opt_state, params)
    return optax.apply_updates(params, updates), opt_state
