"""A trained Dreamer-family agent's parameters with the static facts needed to use them
(what :func:`vsgjax.load` returns as ``run.params``)."""

from __future__ import annotations

import dataclasses

import jax

from vsgjax.agents.dreamer.behaviour import Behaviour
from vsgjax.config import Config


@jax.tree_util.register_pytree_node_class
@dataclasses.dataclass(frozen=True, eq=False)
class TrainedParams:
    """A trained agent's parameters together with the static facts needed to use them.

    A pytree node: its children are the parameter dicts ``wm`` (world model), ``actor`` and
    ``critic`` (``None`` when absent, e.g. a world model trained alone); its aux data is the
    hashable ``(config, action_dim, discrete)``, which JAX treats as static. So a
    ``TrainedParams`` passes through ``jax.jit``, ``jax.tree.map`` or ``jax.device_put`` like
    the dicts it holds (the config becomes part of the compiled program's cache key, as a
    ``static_argnames`` argument would), and :func:`imagine` can read the config, the action
    size and the actor from it instead of asking for them. ``params["wm"]`` also works, as with
    the checkpoint's params dict.
    """

    wm: dict
    actor: dict | None
    critic: dict | None
    config: Config
    action_dim: int
    discrete: bool = False

    def tree_flatten(self):
        return (self.wm, self.actor, self.critic), (self.config, self.action_dim, self.discrete)

    @classmethod
    def tree_unflatten(cls, aux, children):
        return cls(*children, *aux)

    def __getitem__(self, name: str):
        if name not in ("wm", "actor", "critic"):
            raise KeyError(name)
        return getattr(self, name)

    @property
    def behaviour(self) -> Behaviour:
        """The actor-critic networks these params belong to (static, hashable)."""
        return Behaviour.from_config(self.config, self.action_dim, self.discrete)
