"""Model and task names for tests, taken from the registries by property.

A test names a model or a task itself only when it is about that one; a test over several
takes them from here (or from :mod:`vsgjax.registry.agents` directly), so that a new registry
entry is tested wherever its properties say it belongs, and a list of names cannot go stale.
"""

from __future__ import annotations

from vsgjax.registry.agents import (
    AGENTS,
    DEFAULT_MODEL,
    agent_entry,
    dreamer_models,
    gated_models,
    prototype_models,
)
from vsgjax.registry.tasks import DEFAULT_TASK, FAMILIES, family_of

# one task per family, the family's simplest: what a test that covers every family runs
_EXAMPLE_TASKS = (DEFAULT_TASK, "dmc_walker_walk", "atari_pong", "mjx_cartpole_swingup",
                  "gymnax_memory_len")


def models(*, dreamer: bool | None = None, gated: bool | None = None,
           prototypes: bool | None = None, observes: str | None = None) -> tuple[str, ...]:
    """The registered models with the given properties, in registry order (None: either):
    of the Dreamer family, with update gates, learning from prototypes instead of a decoder,
    taking ``observes`` observations (``IMAGE`` or ``VECTOR``)."""
    properties = ((dreamer, dreamer_models()), (gated, gated_models()),
                  (prototypes, prototype_models()))
    return tuple(name for name in AGENTS
                 if all(want is None or (name in have) == want for want, have in properties)
                 and (observes is None or observes in agent_entry(name).observations))


def one_model_per_agent() -> tuple[str, ...]:
    """The default model, then the first registered model of every other agent class."""
    chosen = {agent_entry(DEFAULT_MODEL).implementation: DEFAULT_MODEL}
    for name, entry in AGENTS.items():
        chosen.setdefault(entry.implementation, name)
    return tuple(chosen.values())


def example_task(family: str) -> str:
    """A task of ``family`` (a prefix of the task-family registry)."""
    for task in _EXAMPLE_TASKS:
        if family_of(task).prefix == family:
            return task
    raise ValueError(f"no example task of family {family!r} in tests/support/registry_names.py; "
                     f"it has tasks of {', '.join(family_of(t).prefix for t in _EXAMPLE_TASKS)}")


def example_tasks(observations: str | None = None) -> tuple[str, ...]:
    """One task of every registered family (whose observations are ``observations``)."""
    return tuple(example_task(prefix) for prefix, family in FAMILIES.items()
                 if observations is None or family.observations == observations)
