"""Replay: episodes stored as MCAP files (``store``) and sampled as sequences in memory
(``buffer``).  Typical use in a training loop::

    store = EpisodeStore(logdir / "episodes")
    replay = Replay(capacity, length, rng, oversample_ends)
    for episode in store.load(limit_steps=capacity):   # resume
        replay.add_episode(episode)
    ...
    store.write(episode); replay.add_episode(episode)   # every finished episode
    batch = replay.sample(batch_size)                   # dict of [B, L, ...] numpy arrays
"""

from vsgjax.data.replay.buffer import Replay
from vsgjax.data.replay.store import (
    CorruptEpisodeError,
    EpisodeStore,
    decode_episode,
    encode_episode,
    episode_length,
    read_episode,
)

__all__ = [
    "CorruptEpisodeError",
    "EpisodeStore",
    "Replay",
    "decode_episode",
    "encode_episode",
    "episode_length",
    "read_episode",
]
