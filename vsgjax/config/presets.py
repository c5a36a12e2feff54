"""The presets of a run config: the layers of a task's column, an agent and a size, and the
checks that the agent fits the task and reads the keys given (:func:`~vsgjax.config.make.
make_config` applies them).

The preset tables live with their agents (``vsgjax/agents/<family>/presets.py``: ``COLUMN`` and
``SIZE``) and in the agent registry (:mod:`vsgjax.registry.agents`: what differs between the
agents of one family); the task's preset column comes from the task-family registry
(:mod:`vsgjax.registry.tasks`).
"""

from __future__ import annotations

import importlib
from collections.abc import Sequence

from vsgjax.config.schema import SIZES, ConfigError
from vsgjax.registry.agents import AGENTS, AgentEntry
from vsgjax.registry.names import did_you_mean
from vsgjax.registry.tasks import FAMILIES, VECTOR, TaskError, TaskFamily, family_of

VECTOR_SIZES = ("cpu",)  # sizes with only an MLP encoder: tasks with vector observations


def preset_column(task: str) -> str:
    """The preset column of a task (its family's: ``mjx_`` tasks take the ``dmc`` column)."""
    try:
        return family_of(task).preset_column
    except TaskError as error:
        raise ConfigError(str(error)) from None


def preset_layers(entry: AgentEntry, family: TaskFamily, task: str, size: str) -> list[dict]:
    """The presets of an agent for a task of a family at a size, in the order they apply: the
    column's, the entry's own, the task's (a presets module's ``for_task(name)``, given the
    task name after its family's prefix), the size's. ConfigError when the agent's presets lack
    the family's column."""
    tables, column = importlib.import_module(entry.presets), family.preset_column
    if column not in tables.COLUMN:
        raise ConfigError(f"model {entry.name!r} ({entry.display}) has no presets for the "
                          f"{column!r} column of task {task!r}; its columns: "
                          f"{', '.join(tables.COLUMN)}")
    for_task = getattr(tables, "for_task", lambda name: {})
    return [tables.COLUMN[column], entry.model, entry.by_column.get(column, {}),
            for_task(task.partition("_")[2]), tables.SIZE[size], entry.by_size.get(size, {})]


def check_size(size: str) -> None:
    if size not in SIZES:
        raise ConfigError(f"unknown size {size!r}{did_you_mean(size, SIZES)}; valid: "
                          f"{', '.join(SIZES)}")


def check_agent_fits(entry: AgentEntry, family: TaskFamily, task: str, size: str) -> None:
    """The agent can act in the task's action space and read its observations, and the size
    fits the observations; ConfigError naming the model, the task and why otherwise."""
    if family.actions not in entry.actions:
        raise ConfigError(f"model {entry.name!r} cannot train on {task!r}: the task acts in "
                          f"a {family.actions} action space and {entry.display} acts only in "
                          f"{' or '.join(entry.actions)} action spaces; valid models for "
                          f"{task!r}: {', '.join(_models_for(family))}")
    if family.observations not in entry.observations:
        raise ConfigError(f"model {entry.name!r} cannot train on {task!r}: it reads "
                          f"{' or '.join(entry.observations)} observations, the task gives "
                          f"{family.observations} observations")
    if size in VECTOR_SIZES and family.observations != VECTOR:
        vector_tasks = " or ".join(f.pattern for f in FAMILIES.values()
                                   if f.observations == VECTOR)
        raise ConfigError(f"size {size!r} is for vector observations and task {task!r} has "
                          f"images; valid: {vector_tasks} tasks with {size!r}, or sizes "
                          f"{', '.join(s for s in SIZES if s != size)}")


def _models_for(family: TaskFamily) -> list[str]:
    return [name for name, entry in AGENTS.items()
            if family.actions in entry.actions and family.observations in entry.observations]


def check_keys_for(entry: AgentEntry, keys: Sequence[str]) -> None:
    """Every override key is one the agent reads, and none is ``env.task`` (the task argument,
    which picks the presets); ConfigError naming the key, the model and the models that read
    it."""
    for key in keys:
        if key == "env.task":
            raise ConfigError("config key 'env.task' is the task argument (--task), which "
                              "picks the task's presets; give the task there, not as an "
                              "override")
        readers = [name for name, other in AGENTS.items() if other.takes(key)]
        if readers and not entry.takes(key):  # a key no agent reads is the schema's to refuse
            raise ConfigError(
                f"config key {key!r} is not read by model {entry.name!r} ({entry.display}); "
                f"read by {', '.join(readers)}; its keys: "
                f"{', '.join(f'{s}.*' for s in entry.sections)}, env.*, train.*, model.precision")
