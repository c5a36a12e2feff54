"""Output directories given on a command line (``--logdir``, ``--root``, ``--out``): checked
before anything is written, so that a path that is a file, lies under a file or cannot be
written is a one-line error naming the flag, not a traceback halfway through a run.
"""

from __future__ import annotations

import os
from pathlib import Path

VALID = "valid: a directory, or a path where one can be created"


class OutputDirError(ValueError):
    """An output directory that cannot be used; nothing was written."""


def check_output_dir(path: Path, name: str) -> None:
    """Raise OutputDirError unless ``path`` is a writable directory or can be created."""
    path = Path(path)
    existing = next((p for p in (path, *path.absolute().parents) if p.exists()), None)
    if existing is None:
        return
    if not existing.is_dir():
        where = "is a file" if existing == path else f"is under the file {existing}"
        raise OutputDirError(f"{name} {path} {where}; {VALID}")
    if not os.access(existing, os.W_OK | os.X_OK):
        what = "cannot be written" if existing == path else f"cannot be created in {existing}"
        raise OutputDirError(f"{name} {path} {what} (read-only or no permission); {VALID}")


def make_output_dir(path: Path, name: str) -> None:
    """:func:`check_output_dir`, then create ``path`` and its parents."""
    check_output_dir(path, name)
    try:
        Path(path).mkdir(parents=True, exist_ok=True)
    except OSError as error:
        raise OutputDirError(f"{name} {path} cannot be created: {error.strerror}; "
                             f"{VALID}") from None
