"""Whether a log directory holds the run of its slot: the one truth ``launch --status`` and
``report`` read (a directory of another model, config or seed is neither launched nor counted).
"""

from __future__ import annotations

import functools
import json
from pathlib import Path

from experiments.spec import Run
from vsgjax.config import config_changes, to_dict
from vsgjax.loop.rundir import CONFIG_FILE


def config_difference(run: Run, logdir: Path) -> list[str]:
    """What makes ``logdir/config.json`` another run than ``run``: every key but the resumable
    ones (:data:`vsgjax.config.RESUMABLE_KEYS`) that differs from ``run.config()``, the seed
    included, as ``section.key: saved -> wanted`` (or why the file cannot be read); [] when
    there is no config.json or it agrees."""
    path = Path(logdir) / CONFIG_FILE
    if not path.exists():
        return []
    try:
        saved = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as error:
        return [f"{CONFIG_FILE} unreadable ({error})"]
    if not isinstance(saved, dict):
        return [f"{CONFIG_FILE} unreadable (not a JSON object)"]
    return config_changes(saved, _wanted_config(run))


@functools.cache
def _wanted_config(run: Run) -> dict:
    return to_dict(run.config())
