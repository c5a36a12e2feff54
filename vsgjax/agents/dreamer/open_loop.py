"""Open-loop prediction videos: context frames, then imagined frames.

For one recorded episode, the world model observes the first ``context`` frames (posterior
states, decoded as reconstructions), then rolls its prior forward open loop under the episode's
own actions for the remaining frames. Each video frame is, left to right::

    [ ground truth | sample 1 | ... | sample S ]

where every sample is a separate draw of latent states and gates from the same context.
Videos need images: an episode without an ``image`` key (the MJX tasks' vector observations)
has none (:func:`has_video`).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np

from vsgjax.agents.dreamer import api
from vsgjax.agents.dreamer.networks import float_to_image
from vsgjax.config import Config
from vsgjax.episode_keys import IMAGE_KEY

CONTEXT = 15
HORIZON = 35
SAMPLES = 5


@functools.partial(jax.jit, static_argnames="config")
def _reconstruct(config: Config, params: dict, posts) -> jax.Array:
    """Decoded posterior states [S, T] -> uint8 images [S, T, H, W, C]."""
    model = api.world_model_for(config, params)
    feats = jax.vmap(jax.vmap(model.dynamics.feat))(posts)
    return float_to_image(model.decode_frames(params, feats))


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
    context_seq = {k: v[:, :context] for k, v in seq.items()}
    observe_key, imagine_key = jax.random.split(key)
    posts, _ = api.observe(config, wm_params, context_seq, observe_key)
    start = jax.tree.map(lambda x: x[:, -1], posts)
    imagined = api.imagine(wm_params, start, horizon, config=config, key=imagine_key,
                           actions=seq["action"][:, context:])
    predicted = jnp.concatenate([_reconstruct(config, wm_params, posts), imagined["images"]], 1)
    truth = np.asarray(episode["image"][:length])
    return np.concatenate([truth, *np.asarray(predicted)], axis=2)


def has_video(episode: dict) -> bool:
    """Whether an episode has frames to show: an ``image`` key (vector-only tasks have none,
    and their world model decodes no images)."""
    return IMAGE_KEY in episode


def open_loop_video(config: Config, wm_params: dict, episode: dict, key: jax.Array
                    ) -> np.ndarray | None:
    """Frames for the run's open-loop video, shortening context and horizon (in the 15:35
    ratio) for short episodes or sequences; None when the episode has fewer than 4 steps or
    no images (:func:`has_video`)."""
    if not has_video(episode):
        return None
    available = min(len(episode["image"]), CONTEXT + HORIZON)
    if available < 4:
        return None
    context = max(2, round(available * CONTEXT / (CONTEXT + HORIZON)))
    return open_loop_frames(config, wm_params, episode, key, context, available - context)
