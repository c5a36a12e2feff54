"""``vsgjax.load(logdir)``: a trained run, ready to use from a notebook (docs/notebook.md).

    run = vsgjax.load("runs/bbs_basic-vsg-s0")     # newest checkpoint of the run
    posts = run.observe(run.episode(-1))           # posterior states [T, ...]
    out = vsgjax.imagine(run.params, jax.tree.map(lambda x: x[14], posts), H=15)

``run.params`` is a :class:`vsgjax.agents.dreamer.api.TrainedParams`, which carries the run's
config (for the Dreamer family).
The observation spec and action size come from the newest stored episode (an env is built only
when the run has none).
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from vsgjax.agents import make_agent
from vsgjax.agents.dreamer import api
from vsgjax.agents.dreamer.api import TrainedParams
from vsgjax.agents.dreamer.networks import float_to_image
from vsgjax.agents.dreamer.world_model import WorldModel
from vsgjax.agents.interface import Agent, AgentParams
from vsgjax.config import Config
from vsgjax.data.collect import make_env_batch
from vsgjax.data.replay.store import read_episode
from vsgjax.envs import EnvSpec
from vsgjax.episode_keys import IMAGE_KEY, NON_OBS_KEYS
from vsgjax.loop.run_state import restore_latest
from vsgjax.loop.rundir import RunDir
from vsgjax.observations import ObsSpec
from vsgjax.registry.agents import dreamer_models
from vsgjax.registry.tasks import DISCRETE, family_of

STEP_INPUTS = ("action", "is_first")  # what the posterior reads besides the observations


class TrainedRun:
    """A trained run: ``config``, ``params`` (:class:`TrainedParams` for the models with a
    world model, :class:`~vsgjax.agents.interface.AgentParams` otherwise), ``acting_params``
    (what :meth:`act` reads), the checkpoint's ``step`` (env steps) and ``checkpoint`` path, the
    ``spec`` of its env, its ``agent`` and, for the Dreamer family, ``world_model`` (the
    functions), and its episodes, read on demand."""

    def __init__(self, logdir: Path, config: Config, params: TrainedParams | AgentParams,
                 spec: EnvSpec, step: int, checkpoint: Path):
        self.logdir, self.config, self.params = logdir, config, params
        self.spec, self.step, self.checkpoint = spec, step, checkpoint
        self.acting_params = None

    def __repr__(self) -> str:
        return (f"TrainedRun({str(self.logdir)!r}: task={self.config.env.task} "
                f"model={self.config.agent} size={self.config.size} "
                f"checkpoint at env step {self.step}, {len(self.episode_paths())} episodes)")

    # --- the model's functions -------------------------------------------------------------

    @functools.cached_property
    def agent(self) -> Agent:
        return make_agent(self.config, self.spec)

    @property
    def world_model(self) -> WorldModel:
        """Encoder, dynamics, decoder and heads (``encode``, ``decode``, ``reward_mean`` ...)."""
        if not hasattr(self.agent, "world_model"):
            raise ValueError(f"run {self.logdir} trained model {self.config.agent!r}, which "
                             "has no world model; the models with one: "
                             + ", ".join(dreamer_models()))
        return self.agent.world_model

    @property
    def dynamics(self):
        return self.world_model.dynamics

    @property
    def gated(self) -> bool:
        """Whether the model's states carry gates (VSG, SVSG)."""
        return self.dynamics.gated

    def act(self, obs: dict, carry=None, key: jax.Array | None = None, mode: str = "eval"):
        """One acting step of the trained agent for a batch of observations (any agent):
        ``obs`` holds the observation keys and ``is_first`` ``[N]``; returns ``(carry,
        action)``. ``carry`` defaults to a fresh one, ``key`` to PRNGKey(0)."""
        carry = self.agent.initial_carry(len(obs["is_first"])) if carry is None else carry
        key = jax.random.PRNGKey(api.DEFAULT_SEED) if key is None else key
        return self.agent.policy_step(self.acting_params, carry, obs, key, mode=mode)

    @functools.cached_property
    def policy(self):
        """The trained actor as ``policy(feat, key) -> action`` (a sample, as behaviour learning
        imagines), for ``imagine(..., policy=run.policy)`` or by hand. Cached, so passing it to
        ``imagine`` again reuses the compiled program. :meth:`actor_policy` gives the mode."""
        return self.actor_policy("train")

    def actor_policy(self, mode: str = "train"):
        """``policy(feat, key) -> action``: ``"train"`` samples the actor, ``"eval"`` takes
        its mode (what evaluation runs)."""
        if mode not in ("train", "eval"):
            raise ValueError(f"unknown policy mode {mode!r}; valid: train, eval")
        behaviour, actor = self.params.behaviour, self.params.actor
        return lambda feat, key: behaviour.act(actor, feat, key, mode)

    # --- episodes ----------------------------------------------------------------------------

    def episode_paths(self) -> list[Path]:
        """The run's episode files, oldest first."""
        return RunDir(self.logdir).episode_paths()

    def episode(self, index: int = -1) -> dict[str, np.ndarray]:
        """Episode ``index`` of :meth:`episode_paths` (negative counts from the newest)."""
        paths = self.episode_paths()
        if not paths:
            raise FileNotFoundError(f"no episodes in {self.logdir / 'episodes'}")
        if not -len(paths) <= index < len(paths):
            raise IndexError(f"episode {index} out of range: {self.logdir / 'episodes'} holds "
                             f"{len(paths)} episodes")
        return read_episode(paths[index])

    def iter_episodes(self) -> Iterator[dict[str, np.ndarray]]:
        """Every episode, oldest first, read one at a time."""
        for path in self.episode_paths():
            yield read_episode(path)

    def episodes(self, limit: int | None = None) -> list[dict[str, np.ndarray]]:
        """The newest ``limit`` episodes (all when None), oldest first."""
        paths = self.episode_paths()
        paths = paths if limit is None else paths[max(0, len(paths) - limit):]
        return [read_episode(path) for path in paths]

    # --- using the model ---------------------------------------------------------------------

    def observe(self, episode: dict, key: jax.Array | None = None, *, priors: bool = False):
        """Posterior states of an episode (or a batch of episodes with a leading dim).

        ``episode``: the run's observation keys (``image`` [T, 64, 64, C], ``vector`` [T, D]),
        ``action`` [T, A], ``is_first`` [T] (other keys ignored). Returns the posteriors
        [T, ...] (``[B, T, ...]`` for a batch), or ``(posteriors, priors)`` with
        ``priors=True``. ``key`` defaults to PRNGKey(0).
        """
        spec = self.agent.obs_shape
        batched = len(spec.check(episode)) == 2
        seq = {k: jnp.asarray(episode[k]) for k in (*spec.keys, *STEP_INPUTS)}
        if not batched:
            seq = {k: v[None] for k, v in seq.items()}
        seq["action"] = seq["action"].astype(jnp.float32)
        key = jax.random.PRNGKey(api.DEFAULT_SEED) if key is None else key
        posts, prior_states = api.observe(self.config, self.params.wm, seq, key)
        if not batched:
            posts, prior_states = (jax.tree.map(lambda x: x[0], s) for s in (posts, prior_states))
        return (posts, prior_states) if priors else posts

    def imagine(self, state, H: int = 15, **kwargs) -> dict:
        """``vsgjax.imagine(run.params, state, H, **kwargs)``."""
        return api.imagine(self.params, state, H, **kwargs)

    def decode(self, states) -> jax.Array:
        """uint8 images [..., 64, 64, C] decoded from states with any leading dims."""
        return _decode(self.config, self.params.wm, states)

    def reward(self, states) -> jax.Array:
        """The reward head's mean at states with any leading dims."""
        return _reward(self.config, self.params.wm, states)


def _feats(model: WorldModel, states) -> jax.Array:
    dyn = model.dynamics
    leaf, single = jax.tree.leaves(states)[0], jax.tree.leaves(dyn.initial())[0]
    lead = leaf.shape[: leaf.ndim - single.ndim]
    flat = jax.tree.map(lambda x: x.reshape((-1,) + x.shape[len(lead):]), states)
    feats = jax.vmap(dyn.feat)(flat)
    return feats.reshape(lead + feats.shape[1:])


@functools.partial(jax.jit, static_argnames="config")
def _decode(config: Config, wm_params: dict, states) -> jax.Array:
    model = api.world_model_for(config, wm_params)
    return float_to_image(model.representation.decode_frames(wm_params, _feats(model, states)))


@functools.partial(jax.jit, static_argnames="config")
def _reward(config: Config, wm_params: dict, states) -> jax.Array:
    model = api.world_model_for(config, wm_params)
    return model.reward_mean(wm_params, _feats(model, states))


def env_spec_of(logdir: Path, config: Config) -> EnvSpec:
    """Observation spec and action space of the run's env, from its newest stored episode
    (building one env only when the run has none)."""
    for path in reversed(RunDir(logdir).episode_paths()):
        try:
            episode = read_episode(path)
        except Exception:  # a corrupt file: try the previous one
            continue
        discrete = family_of(config.env.task).actions == DISCRETE
        return EnvSpec(_obs_shape_of(episode), int(episode["action"].shape[-1]), discrete)
    envs = make_env_batch(config.env, config.train.seed, 1, eval=True)
    try:
        return envs.spec
    finally:
        envs.close()


def _obs_shape_of(episode: dict) -> tuple[int, ...] | ObsSpec:
    """An episode's observation keys (all but action, reward and flags) as an EnvSpec's
    ``obs_shape``: the image shape for an image-only episode, as the envs report it."""
    shapes = {k: v.shape[1:] for k, v in episode.items() if k not in NON_OBS_KEYS}
    if list(shapes) == [IMAGE_KEY]:
        return tuple(shapes[IMAGE_KEY])
    return ObsSpec.from_dict(shapes)


def load(logdir: str | Path) -> TrainedRun:
    """The trained run in ``logdir`` at its newest readable checkpoint.

    Raises FileNotFoundError naming the path when ``logdir`` is not a training log directory
    (no ``config.json``) or holds no readable checkpoint.
    """
    logdir = Path(logdir)
    if not logdir.is_dir():
        raise FileNotFoundError(f"{logdir} is not a directory: expected a training log "
                                "directory (config.json, checkpoints/, episodes/)")
    rundir = RunDir(logdir)
    config = rundir.load_config()
    ckpt_dir = rundir.ckpt_dir
    if not rundir.checkpoints():
        raise FileNotFoundError(f"no checkpoint in {ckpt_dir}: {logdir} has no trained state "
                                "yet (checkpoints are written during training)")
    spec = env_spec_of(logdir, config)
    agent = make_agent(config, spec)
    restored = restore_latest(ckpt_dir, agent, jax.random.PRNGKey(config.train.seed))
    if restored is None:
        raise FileNotFoundError(f"no readable checkpoint in {ckpt_dir}")
    state = restored.tree["agent"]
    params = AgentParams(state.params, config)
    if config.agent in dreamer_models():
        params = TrainedParams(state.params["wm"], state.params.get("actor"),
                               state.params.get("critic"), config, spec.action_dim, spec.discrete)
    run = TrainedRun(logdir, config, params, spec, restored.step, restored.path)
    run.agent = agent  # the cached property, already built
    run.acting_params = agent.acting_params(state)
    return run
