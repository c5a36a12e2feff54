"""Imagination actor-critic: λ-returns, actor and critic losses, slow critic.

Pure functions of explicit parameters and PRNG keys, written per start state and vmapped by
the caller; the world model enters only through the callables of :class:`WorldFns`. The two
timestep conventions (``ac.alignment``: ``release`` and ``next_state``) with their alignment
diagrams are in docs/agent.md.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax.scipy.special import ndtri

from vsgjax.agents.dreamer.networks import MLP, normal_log_prob
from vsgjax.agents.dreamer.settings import ACTOR_GRADS, ALIGNMENTS, BehaviourConfig
from vsgjax.agents.precision import compute_dtype
from vsgjax.config import Config

sg = jax.lax.stop_gradient

TRUNC_CLIP = 1e-6  # samples are clipped to [-1 + clip, 1 - clip] so log_prob stays finite
TANH_CLIP = 0.99999997  # |a| is clipped to this before atanh (the release's TanhBijector)
TANH_SAMPLES = 100  # samples of the tanh-normal's entropy and mode (the release's SampleDist)
TAIL = 1e-7  # inverse-CDF levels are kept in [TAIL, 1 - TAIL] so the sample stays finite


# --- action distributions -----------------------------------------------------------------------

class TruncNormalActions(NamedTuple):
    """Continuous actions in [-1, 1]^A: independent Normals truncated to [-1, 1] (DreamerV2).

    ``mean = tanh(m)``, ``std = 2·σ(s/2) + min_std`` from the actor's raw outputs ``(m, s)``.
    With α = (−1 − μ)/σ, β = (1 − μ)/σ and Z = Φ(β) − Φ(α)::

        log p(x) = log φ((x − μ)/σ) − log σ − log Z                 (x in [-1, 1])
        H        = log(√(2πe)·σ·Z) + (α·φ(α) − β·φ(β)) / (2Z)

    Samples come from the inverse CDF and carry the implicit reparameterisation gradient
    dx/dθ = −(∂F(x; θ)/∂θ) / p(x; θ) (F the CDF), as TFP's ``TruncatedNormal``; they are
    clipped to [-1 + 1e-6, 1 − 1e-6] with a straight-through gradient. The mode is the mean.
    Because |μ| ≤ 1 and σ ≤ 2 + min_std, Z ≥ Φ(2/σ_max) − 1/2 ≈ 0.33 (min_std 0.1): no tail
    arithmetic is needed, which compiles to a far smaller graph than TFP's ``TruncatedNormal``
    (several times faster to compile); tests check that the two agree.
    """

    mean: jax.Array
    std: jax.Array

    def _bounds(self) -> tuple[jax.Array, jax.Array, jax.Array]:
        """(α, Φ(α), Z)."""
        alpha, beta = (-1.0 - self.mean) / self.std, (1.0 - self.mean) / self.std
        low = _normal_cdf(alpha)
        return alpha, low, _normal_cdf(beta) - low

    def sample(self, key: jax.Array) -> jax.Array:
        _, low, normalizer = self._bounds()
        level = low + jax.random.uniform(key, self.mean.shape) * normalizer
        event = sg(self.mean + self.std * ndtri(jnp.clip(level, TAIL, 1.0 - TAIL)))
        standard = (event - self.mean) / self.std
        cdf = (_normal_cdf(standard) - low) / normalizer  # forward: `event`; grad: −(∂F/∂θ)/p
        density = sg(_normal_pdf(standard) / (self.std * normalizer))
        event = event - (cdf - sg(cdf)) / density
        clipped = jnp.clip(event, -1.0 + TRUNC_CLIP, 1.0 - TRUNC_CLIP)
        return event + sg(clipped - event)

    def mode(self) -> jax.Array:
        return self.mean

    def log_prob(self, action: jax.Array) -> jax.Array:
        normalizer = self._bounds()[2]
        standard = (action - self.mean) / self.std
        log_density = (-0.5 * standard * standard - 0.5 * jnp.log(2.0 * jnp.pi)
                       - jnp.log(self.std * normalizer))
        return log_density.sum(-1)

    def entropy(self) -> jax.Array:
        alpha, _, normalizer = self._bounds()
        beta = alpha + 2.0 / self.std
        entropy = (0.5 * jnp.log(2.0 * jnp.pi * jnp.e) + jnp.log(self.std * normalizer)
                   + (alpha * _normal_pdf(alpha) - beta * _normal_pdf(beta)) / (2.0 * normalizer))
        return entropy.sum(-1)


def _normal_cdf(x: jax.Array) -> jax.Array:
    """Φ(x) through one erf (absolute accuracy is all the truncated Normal above needs)."""
    return 0.5 * (1.0 + jax.lax.erf(x / jnp.sqrt(2.0)))


def _normal_pdf(x: jax.Array) -> jax.Array:
    return jnp.exp(-0.5 * x * x) / jnp.sqrt(2.0 * jnp.pi)


class TanhNormalActions(NamedTuple):
    """Continuous actions in (-1, 1)^A: ``a = tanh(u)``, ``u ~ N(μ, σ)`` per dimension
    (DreamerV2's ``tanh_normal``, DreamerPro's actor).

    ``μ = 5·tanh(m/5)``, ``σ = softplus(s) + min_std`` from the actor's raw outputs ``(m, s)``;
    ``log p(a) = Σ [log N(u | μ, σ) − log(1 − tanh²(u))]`` with ``u = atanh(a)`` (|a| clipped
    at 0.99999997) and ``log(1 − tanh²(u)) = 2·(log 2 − u − softplus(−2u))``. As the release's
    ``SampleDist``, the entropy is ``−mean log p`` over 100 reparameterised samples and the
    mode the most likely of 100 samples, both drawn with ``key``.
    """

    mean: jax.Array
    std: jax.Array
    key: jax.Array

    def _pre_tanh(self, key: jax.Array, samples: tuple[int, ...] = ()) -> jax.Array:
        noise = jax.random.normal(key, samples + self.mean.shape)
        return self.mean + self.std * noise

    def _log_prob_pre_tanh(self, u: jax.Array) -> jax.Array:
        log_normal = (-0.5 * jnp.square((u - self.mean) / self.std) - jnp.log(self.std)
                      - 0.5 * jnp.log(2.0 * jnp.pi))
        log_det = 2.0 * (jnp.log(2.0) - u - jax.nn.softplus(-2.0 * u))
        return (log_normal - log_det).sum(-1)

    def sample(self, key: jax.Array) -> jax.Array:
        return jnp.tanh(self._pre_tanh(key))

    def log_prob(self, action: jax.Array) -> jax.Array:
        return self._log_prob_pre_tanh(jnp.arctanh(jnp.clip(action, -TANH_CLIP, TANH_CLIP)))

    def entropy(self) -> jax.Array:
        u = self._pre_tanh(self.key, (TANH_SAMPLES,))
        return -jax.vmap(self._log_prob_pre_tanh)(u).mean(0)

    def mode(self) -> jax.Array:
        u = self._pre_tanh(self.key, (TANH_SAMPLES,))
        best = jnp.argmax(jax.vmap(self._log_prob_pre_tanh)(u), axis=0)
        return jnp.tanh(jnp.take_along_axis(u, best[None, ..., None], axis=0)[0])


class OneHotActions(NamedTuple):
    """Discrete actions as one-hot vectors; samples carry a straight-through gradient to the
    probabilities (forward: the one-hot sample; backward: d sample / d probs = identity)."""

    logits: jax.Array

    def sample(self, key: jax.Array) -> jax.Array:
        probs = jax.nn.softmax(self.logits)
        index = jax.random.categorical(key, self.logits)
        one_hot = jax.nn.one_hot(index, self.logits.shape[-1], dtype=probs.dtype)
        return one_hot + (probs - sg(probs))  # exactly one-hot in the forward pass

    def mode(self) -> jax.Array:
        return jax.nn.one_hot(jnp.argmax(self.logits, -1), self.logits.shape[-1])

    def log_prob(self, action: jax.Array) -> jax.Array:
        return jnp.sum(action * jax.nn.log_softmax(self.logits), -1)

    def entropy(self) -> jax.Array:
        log_probs = jax.nn.log_softmax(self.logits)
        return -jnp.sum(jnp.exp(log_probs) * log_probs, -1)


# --- networks -----------------------------------------------------------------------------------

@dataclass(frozen=True)
class Behaviour:
    """Actor and critic networks for one action space; hashable, so usable as a jit static arg.

    ``units`` is the width of the hidden layers (the config's ``wm.mlp_units``: the paper uses
    400 for every MLP). ``precision`` (the config's ``model.precision``) is the compute dtype of
    the actor's and critic's matmuls (:mod:`vsgjax.agents.precision`); their outputs, the action
    distributions, returns and losses are float32.
    """

    cfg: BehaviourConfig
    units: int
    action_dim: int
    discrete: bool
    precision: str = "float32"

    def __post_init__(self):
        if self.cfg.actor_grad not in ACTOR_GRADS:
            raise ValueError(f"unknown ac.actor_grad {self.cfg.actor_grad!r}; "
                             f"valid: {', '.join(ACTOR_GRADS)}")
        if not 0.0 <= self.cfg.actor_grad_mix <= 1.0:
            raise ValueError(f"ac.actor_grad_mix must lie in [0, 1], got {self.cfg.actor_grad_mix}")
        if self.action_dim < 1:
            raise ValueError(f"action_dim must be positive, got {self.action_dim}")
        if self.cfg.alignment not in ALIGNMENTS:
            raise ValueError(f"unknown ac.alignment {self.cfg.alignment!r}; "
                             f"valid: {', '.join(ALIGNMENTS)}")
        _ = self.dtype  # raises on an unknown precision
        if self.imagined_steps < 1:
            raise ValueError(f"ac.horizon {self.cfg.horizon} leaves no imagined step with "
                             f"ac.alignment={self.cfg.alignment}; valid: horizon >= "
                             f"{2 if self.release else 1}")

    @classmethod
    def from_config(cls, config: Config, action_dim: int, discrete: bool) -> Behaviour:
        """The actor-critic of ``config`` (hidden width ``wm.mlp_units``, compute dtype
        ``model.precision``) for an action space."""
        return cls(config.ac, config.wm.mlp_units, action_dim, discrete, config.precision)

    @property
    def dtype(self) -> jnp.dtype:
        """Compute dtype of the actor's and critic's matmuls (``precision``)."""
        return compute_dtype(self.precision)

    @property
    def release(self) -> bool:
        """Whether the release's timestep convention is used (docs/agent.md)."""
        return self.cfg.alignment == "release"

    @property
    def imagined_steps(self) -> int:
        """Prior steps per start: H − 1 (release: H states, the start included) or H."""
        return self.cfg.horizon - 1 if self.release else self.cfg.horizon

    def step_terms(self, reward: jax.Array, discount: jax.Array) -> tuple[jax.Array, jax.Array]:
        """(r_t, d_t) of each step s_t -> s_{t+1} from the heads read at every state.

        release: the heads at s_t (``[:-1]``); next_state: the heads at s_{t+1} (``[1:]``).
        """
        if self.release:
            return reward[:-1], discount[:-1]
        return reward[1:], discount[1:]

    @property
    def dynamics_weight(self) -> float:
        """Weight of the dynamics-backprop objective; the rest goes to REINFORCE.

        'auto' is dynamics backprop for continuous and REINFORCE for discrete actions.
        """
        mode = self.cfg.actor_grad
        if mode == "auto":
            mode = "reinforce" if self.discrete else "dynamics"
        return {"dynamics": 1.0, "reinforce": 0.0, "both": self.cfg.actor_grad_mix}[mode]

    @property
    def actor_net(self) -> MLP:
        outputs = self.action_dim if self.discrete else 2 * self.action_dim
        return MLP(self.cfg.actor_layers, self.units, (outputs,), self.dtype)

    @property
    def critic_net(self) -> MLP:
        return MLP(self.cfg.critic_layers, self.units, (), self.dtype)

    def init(self, key: jax.Array, feat_dim: int) -> dict:
        """{"actor": params, "critic": params, "slow_critic": copy of the critic}."""
        actor_key, critic_key = jax.random.split(key)
        feat = jnp.zeros((feat_dim,), jnp.float32)
        critic = self.critic_net.init(critic_key, feat)["params"]
        return {"actor": self.actor_net.init(actor_key, feat)["params"], "critic": critic,
                "slow_critic": jax.tree.map(jnp.copy, critic)}

    def policy(self, actor_params, feat: jax.Array, key: jax.Array | None = None
               ) -> TruncNormalActions | TanhNormalActions | OneHotActions:
        """The action distribution π(·|feat); ``key`` draws the samples of a tanh-normal's
        entropy and mode (``ac.actor_dist=tanh_normal``; unused otherwise)."""
        out = self.actor_net.apply({"params": actor_params}, feat)
        if self.discrete:
            return OneHotActions(out)
        mean, std = jnp.split(out, 2, axis=-1)
        if self.cfg.actor_dist == "tanh_normal":
            if key is None:
                raise ValueError("a tanh-normal actor needs a key for its sampled entropy "
                                 "and mode")
            return TanhNormalActions(5.0 * jnp.tanh(mean / 5.0),
                                     jax.nn.softplus(std) + self.cfg.actor_min_std, key)
        return TruncNormalActions(jnp.tanh(mean), 2.0 * jax.nn.sigmoid(std / 2.0)
                                  + self.cfg.actor_min_std)

    def act(self, actor_params, feat: jax.Array, key: jax.Array, mode: str = "train"
            ) -> jax.Array:
        """An action of π(·|feat) as float32: a sample (``"train"``) or the mode (``"eval"``)."""
        policy = self.policy(actor_params, feat, key)
        action = policy.sample(key) if mode == "train" else policy.mode()
        return action.astype(jnp.float32)

    def value(self, critic_params, feat: jax.Array) -> jax.Array:
        """The critic's mean value (the mean of a Normal with σ = 1)."""
        return self.critic_net.apply({"params": critic_params}, feat)


# --- returns ------------------------------------------------------------------------------------

def lambda_returns(reward: jax.Array, discount: jax.Array, value: jax.Array,
                   lam: float) -> jax.Array:
    """λ-returns over the time axis 0 from the aligned step terms (docs/agent.md).

    ``reward[t]``, ``discount[t]``: those of the step s_t -> s_{t+1}; ``value[t] = v_{t+1}``,
    the value at the step's end (t = 0..N-1)::

        V_t = reward[t] + discount[t]·((1 − λ)·value[t] + λ·V_{t+1}),   V_N = value[-1]

    λ = 1 gives the discounted Monte-Carlo return bootstrapped with v_N, λ = 0 the one-step
    TD target. Extra trailing axes are batch axes.
    """
    def step(next_return, inputs):
        r, d, v = inputs
        ret = r + d * ((1.0 - lam) * v + lam * next_return)
        return ret, ret

    _, returns = jax.lax.scan(step, value[-1], (reward, discount, value), reverse=True)
    return returns


def return_weights(discount: jax.Array, start_continue: jax.Array) -> jax.Array:
    """w_t = sg(c·Π_{k<t} discount[k]) for the N targets, from the aligned step discounts [N]."""
    ones = jnp.ones_like(discount[:1])
    return sg(start_continue * jnp.cumprod(jnp.concatenate([ones, discount[:-1]]), axis=0))


def update_slow_critic(critic, slow_critic, step: jax.Array, every: int):
    """Hard copy critic → slow critic when ``step`` (updates done before this one) is a multiple
    of ``every``; else unchanged. The release calls it before the update with the critic as it
    is (so the copy at update k = 100 holds the critic after 100 updates); next_state calls it
    after the critic's update (the critic after updates 1, 101, ...)."""
    copy = step % every == 0
    return jax.tree.map(lambda c, s: jnp.where(copy, c, s), critic, slow_critic)


def start_states(posts, is_terminal: jax.Array, behaviour: Behaviour, drop_last: bool):
    """Flattened start states and their continue flags c from [B, T] posteriors.

    release: every posterior except, when ``drop_last`` (a discount head exists), the last time
    step (B·(T − 1) starts, c = 1); next_state: all B·T posteriors, c = 1 − is_terminal.
    """
    if behaviour.release and drop_last:
        posts = jax.tree.map(lambda x: x[:, :-1], posts)
        is_terminal = is_terminal[:, :-1]
    flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[2:]), posts)
    start_continue = 1.0 - is_terminal.reshape(-1).astype(jnp.float32)
    if behaviour.release:
        start_continue = jnp.ones_like(start_continue)
    return flat, start_continue


def draw_starts(starts, start_continue: jax.Array, count: int, key: jax.Array) -> tuple:
    """``count`` of the flattened start states and their flags, drawn uniformly without
    replacement. Posteriors a step apart in one sequence are nearly the same state, so a part
    of them trains the actor-critic almost as well, at that part of imagination's cost."""
    chosen = jax.random.choice(key, start_continue.shape[0], (count,), replace=False)
    return jax.tree.map(lambda x: x[chosen], starts), start_continue[chosen]


# --- imagination and losses ---------------------------------------------------------------------

class Imagined(NamedTuple):
    """One imagined trajectory with everything the losses need (S = N + 1 states, N targets)."""

    feat: jax.Array  # [S, F]
    action: jax.Array  # [S, A]; action[t] was taken in state t, action[-1] is unused
    reward: jax.Array  # [N]; r_t of the step s_t -> s_{t+1} (aligned, see the module docstring)
    discount: jax.Array  # [N]; d_t of that step
    slow_value: jax.Array  # [S]
    returns: jax.Array  # [N]
    weight: jax.Array  # [N], stop-gradient


class WorldFns(NamedTuple):
    """The three world-model callables behaviour learning needs (docs/agent.md)."""

    rollout: Callable
    reward: Callable
    discount: Callable


def imagine(behaviour: Behaviour, actor_params, slow_critic_params, world: WorldFns, start,
            start_continue: jax.Array, key: jax.Array) -> Imagined:
    """Roll the prior ``behaviour.imagined_steps`` steps from ``start`` (stop-gradient) with
    actions sampled from the actor (which sees stop-gradient features, as DreamerV2), then
    compute returns and weights in the configured alignment.

    Gradients w.r.t. ``actor_params`` flow through the sampled actions into every later state,
    reward, discount and slow value (dynamics backprop); the slow critic's parameters are
    constants here.
    """
    def policy(feat, policy_key):
        return behaviour.act(actor_params, sg(feat), policy_key)

    feat, action = world.rollout(policy, jax.tree.map(sg, start), key, behaviour.imagined_steps)
    reward, discount = behaviour.step_terms(world.reward(feat), world.discount(feat))
    slow_value = behaviour.value(sg(slow_critic_params), feat)
    returns = lambda_returns(reward, discount, slow_value[1:], behaviour.cfg.lam)
    return Imagined(feat, action, reward, discount, slow_value, returns,
                    return_weights(discount, start_continue))


def actor_objective(behaviour: Behaviour, actor_params, baseline_params,
                    imagined: Imagined, key: jax.Array) -> tuple:
    """Per-step actor objective for the N targets (to be maximised) and the policy entropy.

    ``baseline_params``: the critic whose value is REINFORCE's baseline (release: the online
    critic; next_state: the slow critic). ``key``: the samples of a tanh-normal's entropy.
    """
    feat = sg(imagined.feat[:-1])
    policy = behaviour.policy(actor_params, feat, key)
    mix = behaviour.dynamics_weight
    objective = jnp.zeros_like(imagined.returns)
    if mix > 0.0:
        objective += mix * imagined.returns
    if mix < 1.0:
        advantage = sg(imagined.returns - behaviour.value(sg(baseline_params), feat))
        objective += (1.0 - mix) * policy.log_prob(sg(imagined.action[:-1])) * advantage
    entropy = policy.entropy()
    return objective + behaviour.cfg.entropy * entropy, entropy


def actor_loss(actor_params, behaviour: Behaviour, critic_params, slow_critic_params,
               world: WorldFns, starts, start_continue: jax.Array, keys: jax.Array) -> tuple:
    """−mean over starts and t of w_t·objective_t; vmapped over the leading axis of ``starts``.

    With pure REINFORCE the imagined trajectory is built from stop-gradient actor parameters
    (no gradient is needed through the dynamics). Returns (loss, (imagined, metrics)).
    """
    rollout_params = actor_params if behaviour.dynamics_weight > 0.0 else sg(actor_params)
    baseline_params = critic_params if behaviour.release else slow_critic_params

    def one_start(start, cont, key):
        imagined = imagine(behaviour, rollout_params, slow_critic_params, world, start, cont, key)
        objective, entropy = actor_objective(behaviour, actor_params, baseline_params, imagined,
                                             jax.random.fold_in(key, 1))
        return -jnp.mean(imagined.weight * objective), (imagined, entropy)

    losses, (imagined, entropy) = jax.vmap(one_start)(starts, start_continue, keys)
    metrics = {
        "actor/loss": losses.mean(),
        "actor/entropy": entropy.mean(),
        "imag/reward": imagined.reward.mean(),
        "imag/discount": imagined.discount.mean(),
        "imag/return": imagined.returns.mean(),
        "imag/weight": imagined.weight.mean(),
        "critic/slow_value": imagined.slow_value.mean(),
    }
    return losses.mean(), (jax.tree.map(sg, imagined), metrics)


def critic_loss(critic_params, behaviour: Behaviour, imagined: Imagined) -> tuple:
    """−mean(w_t · log N(sg(V_t) | v(sg(feat_t)), 1)) over starts and the N targets.

    Features, targets and weights are stop-gradient, so this loss trains the critic only.
    """
    value = behaviour.value(critic_params, sg(imagined.feat[..., :-1, :]))
    log_prob = normal_log_prob(value, sg(imagined.returns))
    loss = -jnp.mean(sg(imagined.weight) * log_prob)
    return loss, {"critic/loss": loss, "critic/value": value.mean()}
