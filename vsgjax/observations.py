"""Observation specs: which observation keys a world model reads, and their shapes.

An :class:`ObsSpec` is a sorted tuple of ``(key, shape)`` pairs (hashable, so usable as a jit
static). The rank of a shape says what a key holds:

* an *image* key: rank 3, ``(H, W, C)``, uint8 pixels (the CNN encoder and decoder);
* a *vector* key: rank 1, ``(D,)``, float32 (the MLP encoder and decoder).

Conventions: pixels live under ``"image"`` (today's ``obs_shape`` ``(64, 64, C)`` is the spec
``{"image": (64, 64, C)}``), and proprioceptive MJX tasks put their flat observation
(``MjxTask.flat_obs``) under ``"vector"``, so a [B, T] batch is ``{"vector": [B, T, D] float32,
"action", "reward", "is_first", "is_terminal"}``. Observations (a step, a sequence or a batch)
are dicts with the spec's keys and any leading dimensions; other keys are ignored.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from vsgjax.episode_keys import IMAGE_DTYPE, IMAGE_KEY, NON_OBS_KEYS, VECTOR_DTYPE

_KINDS = "rank 3 (H, W, C) for an image or rank 1 (D,) for a vector"


@dataclass(frozen=True)
class ObsSpec:
    """``((key, shape), ...)`` sorted by key: image keys rank 3, vector keys rank 1.

    Build one with :meth:`from_image_shape`, :meth:`from_dict` or :func:`obs_spec`; the
    constructor validates its entries as :meth:`from_dict` does.
    """

    entries: tuple[tuple[str, tuple[int, ...]], ...]

    def __post_init__(self):
        checked = tuple(sorted(_check_entry(key, shape) for key, shape in self.entries))
        keys = [key for key, _ in checked]
        if not keys:
            raise ValueError(f"an observation spec needs at least one key ({_KINDS})")
        if len(set(keys)) != len(keys):
            raise ValueError(f"observation keys repeat: {keys}")
        object.__setattr__(self, "entries", checked)

    @classmethod
    def from_image_shape(cls, shape: Sequence[int]) -> ObsSpec:
        """``(H, W, C)`` -> ``{"image": (H, W, C)}`` (today's ``obs_shape``)."""
        return cls(((IMAGE_KEY, shape),))

    @classmethod
    def from_dict(cls, shapes: Mapping[str, Sequence[int]]) -> ObsSpec:
        """``{key: shape}`` -> spec; a shape of rank 3 is an image, of rank 1 a vector."""
        return cls(tuple(shapes.items()))

    @property
    def shapes(self) -> dict[str, tuple[int, ...]]:
        return dict(self.entries)

    @property
    def keys(self) -> tuple[str, ...]:
        return tuple(key for key, _ in self.entries)

    @property
    def image_keys(self) -> tuple[str, ...]:
        return tuple(key for key, shape in self.entries if len(shape) == 3)

    @property
    def vector_keys(self) -> tuple[str, ...]:
        return tuple(key for key, shape in self.entries if len(shape) == 1)

    @property
    def vector_size(self) -> int:
        """Total size of the vector keys (their concatenation, in key order)."""
        return sum(self.shapes[key][0] for key in self.vector_keys)

    def dtype(self, key: str) -> np.dtype:
        """uint8 for an image key, float32 for a vector key."""
        return IMAGE_DTYPE if len(self.shapes[key]) == 3 else VECTOR_DTYPE

    def check(self, obs: Mapping) -> tuple[int, ...]:
        """The leading dims ``obs``'s spec keys share; raises unless every key is there with
        the spec's shape after them (shapes only: works on tracers inside jit)."""
        leads = {}
        for key, shape in self.entries:
            if key not in obs:
                raise ValueError(f"observations lack key {key!r} of the spec {self.shapes}; "
                                 f"got keys {sorted(obs)}")
            got = tuple(np.shape(obs[key]))
            if got[len(got) - len(shape):] != shape or len(got) < len(shape):
                raise ValueError(f"observation {key!r} has shape {got}; the spec wants "
                                 f"[..., {', '.join(map(str, shape))}]")
            leads[key] = got[:len(got) - len(shape)]
        if len(set(leads.values())) > 1:
            raise ValueError(f"observation keys disagree on their leading dims: {leads}")
        return next(iter(leads.values()))

def obs_spec(spec: ObsSpec | Mapping[str, Sequence[int]] | Sequence[int]) -> ObsSpec:
    """An :class:`ObsSpec` from a spec, a ``{key: shape}`` dict or an image shape ``(H, W, C)``."""
    if isinstance(spec, ObsSpec):
        return spec
    if isinstance(spec, Mapping):
        return ObsSpec.from_dict(spec)
    return ObsSpec.from_image_shape(spec)


def _check_entry(key, shape) -> tuple[str, tuple[int, ...]]:
    """``(key, shape)`` with int dims, or a ValueError naming the key and what is valid."""
    if not isinstance(key, str) or not key.isidentifier():
        raise ValueError(f"observation key {key!r} must be a Python identifier string")
    if key in NON_OBS_KEYS:
        raise ValueError(f"observation key {key!r} is taken by the batch; reserved: "
                         f"{', '.join(NON_OBS_KEYS)}")
    try:
        dims = tuple(int(d) for d in shape)
    except (TypeError, ValueError):
        raise ValueError(f"observation {key!r} has shape {shape!r}: want {_KINDS}") from None
    if len(dims) not in (1, 3) or min(dims) < 1:
        raise ValueError(f"observation {key!r} has shape {dims}: want {_KINDS}, "
                         f"every dim positive")
    return key, dims
