"""Which loop trains a config: ``train.loop`` resolved against the task's family."""

from __future__ import annotations

from vsgjax.config import Config, ConfigError
from vsgjax.registry.tasks import device_families, family_of


def resolve_loop(config: Config) -> str:
    """``host`` or ``device`` for ``train.loop`` (``auto``: device for tasks that step in JAX,
    which the host loop drives too, through their vector env); raises ConfigError for the
    device loop on a host task."""
    task, loop = config.env.task, config.train.loop
    on_device = family_of(task).on_device
    if loop == "auto":
        return "device" if on_device else "host"
    if loop == "device" and not on_device:
        raise ConfigError("train.loop=device needs a task that steps inside JAX ("
                          + ", ".join(f.pattern for f in device_families()) + f"); {task!r} is "
                          "a host environment (gymnasium, stepped in Python): use "
                          "train.loop=host or auto")
    return loop
