"""In-memory replay: whole episodes in a ring buffer of steps, uniform length-L sequence sampling.

Storage: one preallocated array per key of shape ``[capacity, ...]`` (grown by doubling up to
``capacity`` so a small run does not reserve the full capacity; each doubling copies the
stored steps once), used as a ring.  Episodes are
stored contiguously (modulo ``capacity``) in arrival order; adding an episode evicts the
oldest *whole* episodes until it fits.  Images stay uint8: the memory per stored step is
``bytes_per_step`` (12,288 image bytes + action/reward/flags for 64x64x3).

Sampling rule (``sample``): every returned sequence is ``L`` consecutive steps of ONE episode,
so ``is_first`` can only be True at index 0 of a sequence, and only when the sequence starts
at its episode's first step.  Episodes shorter than ``L`` are kept (they count towards the
capacity and are saved on disk) but never sampled.

* ``oversample_ends=False``: uniform over all valid (episode, start) pairs: an episode of
  length n is chosen with probability proportional to its n - L + 1 start positions, then the
  start uniformly in [0, n - L].  Steps near either end of an episode are covered by fewer
  sequences than steps in the middle.
* ``oversample_ends=True`` (DreamerV2's ``balance``): the episode is chosen proportionally to
  its length n, then ``start = min(k, n - L)`` with k uniform in [0, n).  The last start
  position absorbs the L - 1 draws past it, so the last step of an episode lies in a sampled
  sequence as often as a middle step (probability L / sum(n) each) instead of L times less
  often; the L - 1 steps before it are covered up to twice as often, and step t < L of the
  start is covered (t + 1) / L as often as the middle, as in DreamerV2.  DreamerV2 draws the
  episode uniformly instead of proportionally to n; the two agree when all episodes have one
  length (fixed time limits), and the weighting here keeps the coverage of middle steps
  equal across episodes of different lengths.

``history=h`` (frame stacking, e.g. DrQ-v2's): each sequence comes with the ``h`` steps before
it, ``[B, h + L]``, where a step before the episode's first repeats the first (the start is
drawn as without history, so ``is_first`` is True only at the history's steps or step ``h``).

All randomness comes from the numpy Generator given to the constructor (``self.rng``; save
``rng.bit_generator.state`` in checkpoints): same seed and same episodes give the same batches.
"""

from __future__ import annotations

import collections
from collections.abc import Mapping

import numpy as np

from vsgjax.data.replay.store import episode_length


class Replay:
    """A capacity-bounded episode replay buffer sampling [B, L] sequence batches."""

    def __init__(
        self,
        capacity: int,
        length: int,
        rng: np.random.Generator | int,
        oversample_ends: bool = False,
        *,
        history: int = 0,
    ):
        if length < 1:
            raise ValueError(f"sequence length must be >= 1, got {length}")
        if history < 0:
            raise ValueError(f"history must be >= 0 steps, got {history}")
        if capacity < length:
            raise ValueError(f"capacity ({capacity}) must be at least the length ({length})")
        self.capacity = capacity
        self.length = length
        self.history = history
        self.oversample_ends = oversample_ends
        self.rng = np.random.default_rng(rng)
        self._buffers: dict[str, np.ndarray] = {}
        self._episodes: collections.deque[tuple[int, int]] = collections.deque()  # (start, n)
        self._head = 0  # ring position where the next episode starts
        self._num_steps = 0
        self._table: tuple[np.ndarray, ...] | None = None

    @property
    def num_steps(self) -> int:
        return self._num_steps

    @property
    def num_episodes(self) -> int:
        return len(self._episodes)

    @property
    def num_sequences(self) -> int:
        """Number of distinct length-L sequences that can be sampled (0: cannot sample)."""
        return int(sum(max(0, n - self.length + 1) for _, n in self._episodes))

    @property
    def bytes_per_step(self) -> int:
        """Memory of one stored step over all keys (0 before the first episode)."""
        return sum(b.itemsize * int(np.prod(b.shape[1:])) for b in self._buffers.values())

    @property
    def nbytes(self) -> int:
        """Memory currently allocated for stored steps."""
        return sum(b.nbytes for b in self._buffers.values())

    def add_episode(self, episode: Mapping[str, np.ndarray]) -> None:
        """Store a complete episode (format: ``vsgjax.data.replay.store``), evicting the oldest."""
        n = episode_length(episode)
        if n > self.capacity:
            raise ValueError(f"episode of {n} steps exceeds the replay capacity {self.capacity}")
        self._check_or_set_layout(episode)
        while self._num_steps + n > self.capacity:
            _, evicted = self._episodes.popleft()
            self._num_steps -= evicted
        self._reserve(self._head + n)
        positions = (self._head + np.arange(n)) % self.capacity
        for key, buffer in self._buffers.items():
            buffer[positions] = episode[key]
        self._episodes.append((self._head, n))
        self._head = (self._head + n) % self.capacity
        self._num_steps += n
        self._table = None

    def _check_or_set_layout(self, episode: Mapping[str, np.ndarray]) -> None:
        """The first episode fixes the keys, dtypes and per-step shapes; later ones must match."""
        if not self._buffers:
            self._buffers = {
                key: np.empty((0, *value.shape[1:]), value.dtype) for key, value in episode.items()
            }
            return
        for key, buffer in self._buffers.items():
            value = episode.get(key)
            if value is None or value.dtype != buffer.dtype or value.shape[1:] != buffer.shape[1:]:
                got = None if value is None else f"{value.dtype}{list(value.shape[1:])}"
                raise ValueError(
                    f"episode[{key!r}] is {got}, replay stores {buffer.dtype}"
                    f"{list(buffer.shape[1:])} per step"
                )
        extra = set(episode) - set(self._buffers)
        if extra:
            raise ValueError(f"episode has keys {sorted(extra)} the replay does not store")

    def _reserve(self, size: int) -> None:
        """Grow the buffers (by doubling, at most to capacity) to hold ring positions < size.

        Before the first eviction the ring has never wrapped, so ``_head`` equals the number of
        stored steps and growing keeps every stored position; from the first eviction on,
        ``size`` exceeds the capacity and the buffers are at full capacity.
        """
        allocated = len(next(iter(self._buffers.values())))
        if size <= allocated or allocated == self.capacity:
            return
        new_size = min(self.capacity, max(size, 2 * allocated))
        for key, buffer in self._buffers.items():
            grown = np.empty((new_size, *buffer.shape[1:]), buffer.dtype)
            grown[:allocated] = buffer
            self._buffers[key] = grown

    def _sampling_table(self) -> tuple[np.ndarray, ...]:
        """Ring starts, lengths and [begin, end) draw ranges of the episodes with >= L steps.

        An episode owns the integers [begin, end) of one draw in [0, total); the width of
        its range is its sampling weight.
        """
        if self._table is None:
            eligible = np.array(
                [(start, n) for start, n in self._episodes if n >= self.length], np.int64
            ).reshape(-1, 2)
            starts, lengths = eligible[:, 0], eligible[:, 1]
            weights = lengths if self.oversample_ends else lengths - self.length + 1
            ends = np.cumsum(weights)
            self._table = (starts, lengths, ends - weights, ends)
        return self._table

    def sample(self, batch_size: int) -> dict[str, np.ndarray]:
        """A batch of ``batch_size`` sequences: dict of arrays with leading dims
        ``[B, history + L]``."""
        starts, lengths, begins, ends = self._sampling_table()
        if len(lengths) == 0:
            raise ValueError(
                f"replay holds no episode of at least {self.length} steps "
                f"({self.num_episodes} episodes, {self.num_steps} steps)"
            )
        draws = self.rng.integers(0, ends[-1], size=batch_size)
        episode = np.searchsorted(ends, draws, side="right")
        offset = draws - begins[episode]
        if self.oversample_ends:
            offset = np.minimum(offset, lengths[episode] - self.length)
        steps = np.maximum(offset[:, None] + np.arange(-self.history, self.length), 0)
        positions = (starts[episode][:, None] + steps) % self.capacity
        return {key: buffer[positions] for key, buffer in self._buffers.items()}
