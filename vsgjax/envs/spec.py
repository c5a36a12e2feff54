"""What the rest of the package knows about an env: its spec, task-name errors, seeds."""

from __future__ import annotations

from typing import NamedTuple

from vsgjax.observations import ObsSpec, obs_spec
from vsgjax.registry.names import did_you_mean
from vsgjax.registry.tasks import TaskError

__all__ = ["EVAL_SEED_OFFSET", "EnvSpec", "TaskError", "one_of"]

EVAL_SEED_OFFSET = 1_000_000  # eval env seeds are seed + offset, never a training env's seed


def one_of(task: str, name: str, valid, what: str) -> str:
    """``name`` if it is in ``valid``, else a TaskError listing the valid task names."""
    if name not in valid:
        family = task.partition("_")[0]
        hint = did_you_mean(name, valid, prefix=f"{family}_")
        raise TaskError(f"unknown {what} in {task!r}{hint}; valid: "
                        + ", ".join(f"{family}_{v}" for v in valid))
    return name


class EnvSpec(NamedTuple):
    """What the model needs to know about an env, as plain values.

    ``obs_shape``: the image shape ``(H, W, C)`` of an image env, or the :class:`ObsSpec` of an
    env with observation dicts (what ``Agent`` takes as ``obs_shape`` either way).
    """

    obs_shape: tuple[int, int, int] | ObsSpec
    action_dim: int
    discrete: bool

    @property
    def obs(self) -> ObsSpec:
        """The observation spec (an image env's is ``{"image": (H, W, C)}``)."""
        return obs_spec(self.obs_shape)
