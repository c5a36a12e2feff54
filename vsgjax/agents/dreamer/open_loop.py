"""The paper's open-loop test: the world model observes ``context`` steps of a recorded episode,
then imagines the next ``horizon`` steps under the episode's own actions; as videos, and as
numbers (the prediction error at each imagined step).

Both use :func:`observe_then_imagine`. The alignment, in the episode format (step ``t`` holds
observation ``t``, the reward ``r_t`` that came with it and the action ``a_t`` that led to it;
``a_0 = 0`` at ``is_first``)::

    observe  steps 0 .. C-1                    -> posterior s_{C-1}
    imagine  k = 1 .. H:  s'_k = prior(s'_{k-1}, a_{C+k-1})   (s'_0 = s_{C-1})
    compare  decode(s'_k) with observation C+k-1, reward_head(s'_k) with r_{C+k-1}

so imagined step 1 predicts step C (the first step the model did not see) from the action
taken after step C-1, and imagined step H predicts step C+H-1 (C = 15, H = 35: steps 15..49).

**Videos.** Each video frame is, left to right::

    [ ground truth | sample 1 | ... | sample S ]

where every sample is a separate draw of latent states and gates from the same context
(reconstructions of the posteriors during the context). Videos need images: an episode without
an ``image`` key (the MJX tasks' vector observations) has none (:func:`has_video`).

**Errors.** :func:`open_loop_errors` gives, per imagined step, the mean squared error of the
decoded mean observation and of the reward head's mean, averaged over the episodes of a batch
and over every observation value (:func:`open_loop_errors` says in which units). Both loops
log it at every evaluation through the agent hook ``open_loop_errors`` (``open_loop.jsonl``
in the run directory, docs/training.md).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from vsgjax.agents.dreamer.inference import imagine, observe, world_model_for
from vsgjax.agents.dreamer.networks import float_to_image, image_to_float
from vsgjax.agents.dreamer.world_model import WorldModel
from vsgjax.config import Config
from vsgjax.episode_keys import IMAGE_KEY

CONTEXT = 15
HORIZON = 35
SAMPLES = 5
MIN_STEPS = 4  # the shortest episode the shortened test runs on (2 context + 2 imagined)
ERROR_INPUTS = ("action", "reward", "is_first")  # what the errors read besides observations


@functools.partial(jax.jit, static_argnames="config")
def _reconstruct(config: Config, params: dict, posts) -> jax.Array:
    """Decoded posterior states [S, T] -> uint8 images [S, T, H, W, C]."""
    model = world_model_for(config, params)
    feats = jax.vmap(jax.vmap(model.dynamics.feat))(posts)
    return float_to_image(model.representation.decode_frames(params, feats))


def observe_then_imagine(config: Config, wm_params: dict, seq: dict, key: jax.Array,
                         context: int, horizon: int) -> tuple:
    """The open-loop test's two passes on a batch of sequences ``[N, >= context + horizon]``
    (the episode keys, starting at an episode's first step): the posteriors of steps
    ``0 .. context-1`` and :func:`vsgjax.agents.dreamer.inference.imagine`'s ``horizon`` imagined
    steps from the last one under the actions ``context .. context+horizon-1`` (the
    alignment in the module docstring). ``key`` is split into the observing and the imagining
    key. Returns ``(posts [N, context], imagined [N, horizon])``."""
    observe_key, imagine_key = jax.random.split(key)
    posts, _ = observe(config, wm_params, {k: v[:, :context] for k, v in seq.items()},
                           observe_key)
    start = jax.tree.map(lambda x: x[:, -1], posts)
    imagined = imagine(wm_params, start, horizon, config=config, key=imagine_key,
                           actions=seq["action"][:, context:context + horizon])
    return posts, imagined


def open_loop_frames(config: Config, wm_params: dict, episode: dict, key: jax.Array,
                     context: int = CONTEXT, horizon: int = HORIZON,
                     samples: int = SAMPLES) -> np.ndarray:
    """uint8 frames [context + horizon, H, (1 + samples) * W, C] (see module docstring).

    ``episode`` needs at least ``context + horizon`` steps, starting at its first step.
    """
    length = context + horizon
    if len(episode["image"]) < length:
        raise ValueError(f"episode of {len(episode['image'])} steps is shorter than "
                         f"context + horizon = {length}")
    seq = {k: jnp.repeat(jnp.asarray(v[None, :length]), samples, axis=0)
           for k, v in episode.items()}
    posts, imagined = observe_then_imagine(config, wm_params, seq, key, context, horizon)
    predicted = jnp.concatenate([_reconstruct(config, wm_params, posts), imagined["images"]], 1)
    truth = np.asarray(episode["image"][:length])
    return np.concatenate([truth, *np.asarray(predicted)], axis=2)


def open_loop_errors(config: Config, wm_params: dict, episodes: dict, key: jax.Array,
                     context: int = CONTEXT, horizon: int = HORIZON) -> dict[str, jax.Array]:
    """The world model's open-loop prediction error at each imagined step, ``{"obs_mse":
    [horizon], "reward_mse": [horizon]}`` (float32), on a batch of episodes ``[N, T]`` with
    ``T >= context + horizon`` (the episode keys, each starting at its first step; other keys
    are ignored).

    Entry ``k - 1`` is imagined step ``k``, which predicts episode step ``context + k - 1``
    (the alignment in the module docstring). ``obs_mse``: the squared difference between the
    decoder's mean and the recorded observation, averaged over the N episodes and over every
    observation value (each pixel channel and each vector entry counts once; with both an
    image and vectors they are pooled). Pixels are compared in the decoder's float scale,
    ``uint8 / 255 - 0.5`` (the ``wm/image_mse`` metric's units: the MSE of pixels in [0, 1]);
    vectors as recorded. ``reward_mse``: the reward head's mean against the recorded reward, in
    the head's units (``tanh(reward)`` when ``wm.reward_tanh``), averaged over the episodes.
    One sample of the latent states per episode (``key`` as :func:`observe_then_imagine`).
    A model without a decoder (DreamerPro's prototypes) predicts no observation: its
    ``obs_mse`` is NaN (null in ``open_loop.jsonl``).
    Pure JAX: jitted, and usable inside a compiled program (the device loop's evaluation).
    """
    if context < 1 or horizon < 1:
        raise ValueError(f"context and horizon must be >= 1, got {context} and {horizon}")
    steps = episodes["action"].shape[1]
    if steps < context + horizon:
        raise ValueError(f"episodes of {steps} steps are shorter than context + horizon = "
                         f"{context + horizon}")
    model = world_model_for(config, wm_params)
    seq = {k: jnp.asarray(episodes[k])[:, :context + horizon]
           for k in (*model.obs_shape.keys, *ERROR_INPUTS)}
    return _errors(config, wm_params, seq, key, context, horizon)


@functools.partial(jax.jit, static_argnames=("config", "context", "horizon"))
def _errors(config: Config, wm_params: dict, seq: dict, key: jax.Array, context: int,
            horizon: int) -> dict[str, jax.Array]:
    model = world_model_for(config, wm_params)
    _, imagined = observe_then_imagine(config, wm_params, seq, key, context, horizon)
    truth = {k: v[:, context:] for k, v in seq.items()}
    if model.representation.decodes:
        obs_mse = _observation_mse(model, imagined, truth)
    else:
        obs_mse = jnp.full(horizon, jnp.nan)
    reward = truth["reward"].astype(jnp.float32)
    if config.wm.reward_tanh:
        reward = jnp.tanh(reward)
    reward_mse = jnp.square(imagined["rewards"].astype(jnp.float32) - reward).mean(0)
    return {"obs_mse": obs_mse, "reward_mse": reward_mse}


def _observation_mse(model: WorldModel, imagined: dict, truth: dict) -> jax.Array:
    """[H] squared error of the decoded means, averaged over the episodes and every
    observation value (pixels in the decoder's float scale)."""
    squared, values = [], 0
    if model.has_image:
        error = imagined["image_means"].astype(jnp.float32) - image_to_float(truth[IMAGE_KEY])
        squared.append(jnp.square(error).reshape(error.shape[:2] + (-1,)).sum(-1))
        values += int(np.prod(error.shape[2:]))
    for name in model.vector_keys:
        error = (imagined["vectors"][name].astype(jnp.float32)
                 - truth[name].astype(jnp.float32))
        squared.append(jnp.square(error).sum(-1))
        values += error.shape[-1]
    return (sum(squared) / max(values, 1)).mean(0)


def shortened(steps: int) -> tuple[int, int] | None:
    """``(context, horizon)`` for episodes of ``steps`` steps: 15 and 35, or for shorter ones
    the steps there are split in the 15:35 ratio (at least 2 context steps); None below
    ``MIN_STEPS`` steps."""
    available = min(steps, CONTEXT + HORIZON)
    if available < MIN_STEPS:
        return None
    context = max(2, round(available * CONTEXT / (CONTEXT + HORIZON)))
    return context, available - context


def shortened_open_loop_errors(config: Config, wm_params: dict, episodes: dict,
                               key: jax.Array) -> dict[str, jax.Array] | None:
    """:func:`open_loop_errors` at 15 + 35 steps, shortened for episodes of fewer than 50
    steps (:func:`shortened`: then ``horizon`` < 35 entries); None for episodes of fewer than
    ``MIN_STEPS`` steps. What the loops log at every evaluation."""
    split = shortened(episodes["action"].shape[1])
    if split is None:
        return None
    return open_loop_errors(config, wm_params, episodes, key, *split)


def has_video(episode: dict) -> bool:
    """Whether an episode has frames to show: an ``image`` key (vector-only tasks have none,
    and their world model decodes no images)."""
    return IMAGE_KEY in episode


def open_loop_video(config: Config, wm_params: dict, episode: dict, key: jax.Array
                    ) -> np.ndarray | None:
    """Frames for the run's open-loop video, shortening context and horizon (in the 15:35
    ratio, :func:`shortened`) for short episodes or sequences; None when the episode has fewer
    than 4 steps, no images (:func:`has_video`) or a model without a decoder."""
    if not has_video(episode) or not world_model_for(config, wm_params).representation.decodes:
        return None
    split = shortened(len(episode["image"]))
    if split is None:
        return None
    return open_loop_frames(config, wm_params, episode, key, *split)
