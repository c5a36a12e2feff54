"""What training checks and does before it writes into a run directory, so that a run is never
silently replaced, mixed with another or pruned of its only good data.

* the directory exists or is created (:func:`vsgjax.outdir.make_output_dir`).
* :class:`RunLock`: one training process per run directory.
* :func:`move_aside`: the old contents (``--restart``; a first attempt killed before its first
  checkpoint and evaluation), or the episodes a killed run wrote after its newest checkpoint,
  go to ``previous/<UTC time>/`` (process logs stay); nothing is deleted.
* :func:`survey_checkpoints`: the run's config (``config.json``, else its newest checkpoint's),
  its corrupt checkpoints and another run's (one whose config differs); when no checkpoint of
  the run's own is left, or its config cannot be told, the run is refused, nothing touched.
* :func:`set_aside_corrupt`, :func:`set_aside`: a corrupt checkpoint goes to
  ``checkpoints/corrupt/``, another run's to ``checkpoints/foreign/`` (out of the kept ones).
* :func:`remove_interrupted_writes`: the temporary files of writes that a killed process left
  unfinished (never renamed into place, so never data) are removed.
"""

from __future__ import annotations

import datetime
import fcntl
import os
import warnings
from pathlib import Path
from typing import NamedTuple

from vsgjax.config import config_changes
from vsgjax.data import checkpoint

LOCK_FILE = ".lock"
PROCESS_LOG_SUFFIX = ".log"  # a launcher's log of the process writing the run: never moved
PREVIOUS_DIR = "previous"  # ``--restart`` moves the old contents into previous/<UTC time>/
CORRUPT_DIR = "corrupt"  # under checkpoints/
FOREIGN_DIR = "foreign"  # under checkpoints/: another run's checkpoints
RESTART_HINT = ("rerun with --restart to move the old contents to {previous}/ and start over, "
                "or use another --logdir")


class RunDirError(ValueError):
    """A run directory training cannot write into as asked (nothing in it was changed)."""


def restart_hint(logdir: Path) -> str:
    return RESTART_HINT.format(previous=logdir / PREVIOUS_DIR / "<time>")


class RunLock:
    """An exclusive lock on ``<logdir>/.lock``, held while a training process writes the run.

    ``fcntl.flock`` rather than a pid file alone: the kernel drops the lock when its holder's
    file is closed, which happens however the process ends (SIGKILL included), so a lock left
    by a killed process is taken over by the next run with no staleness check. The file holds
    the holder's pid for the message of a second process. (The lock is not inherited across
    ``exec``; env workers are spawned, so they do not keep it.)
    """

    def __init__(self, logdir: Path):
        self.path = logdir / LOCK_FILE
        try:
            self._file = open(self.path, "a+")  # held open: the lock lives with it
        except OSError as error:
            raise RunDirError(f"log directory {logdir} cannot be written: "
                              f"{error.strerror}") from None
        try:
            fcntl.flock(self._file, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._file.seek(0)
            holder = self._file.read().strip() or "unknown"
            self._file.close()
            raise RunDirError(f"log directory {logdir} is in use by another training process "
                              f"(pid {holder}, which holds {self.path}); wait for it to end or "
                              "stop it, or use another --logdir") from None
        self._file.seek(0)
        self._file.truncate()
        self._file.write(f"{os.getpid()}\n")
        self._file.flush()

    def unlock(self) -> None:
        self._file.close()


def move_aside(logdir: Path, entries: list[Path] | None = None) -> Path | None:
    """Move ``entries`` of ``logdir`` (by default every entry but the lock, ``previous/`` and
    process logs ``*.log``, which a launcher keeps open and appends to across attempts) into
    ``previous/<UTC time>/``, each at its path relative to ``logdir``; returns that directory
    (None when there was nothing to move)."""
    if entries is None:
        entries = [p for p in sorted(logdir.iterdir())
                   if p.name not in (LOCK_FILE, PREVIOUS_DIR) and p.suffix != PROCESS_LOG_SUFFIX]
    if not entries:
        return None
    stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%SZ")
    target = _unused(logdir / PREVIOUS_DIR / stamp)
    for entry in entries:
        moved = target / entry.relative_to(logdir)
        moved.parent.mkdir(parents=True, exist_ok=True)
        entry.rename(moved)
    return target


class Survey(NamedTuple):
    """What a run directory's checkpoints say about the run (read; nothing changed)."""

    corrupt: dict[Path, str]  # a corrupt checkpoint -> what is wrong with it
    foreign: dict[Path, str]  # another run's checkpoint -> how its config differs
    config: dict | None  # the run's config: config.json's, else the newest checkpoint's
    config_from: Path | None  # that checkpoint, when config.json is missing


def survey_checkpoints(logdir: Path, ckpt_dir: Path, saved_config: dict | None) -> Survey:
    """Read every checkpoint's header, CRC and meta, and tell the run's own from the corrupt
    ones and from another run's (a checkpoint whose config differs from ``saved_config``,
    the run's ``config.json``; when that is None, from the newest checkpoint's config).
    RunDirError, nothing changed, when no checkpoint is left to resume from, or when there is
    no ``config.json`` and no checkpoint holds its config (written before checkpoints did)."""
    corrupt, configs = {}, {}
    for _, path in checkpoint.list_checkpoints(ckpt_dir):
        try:
            configs[path] = checkpoint.read_meta(path).get("config")
        except (checkpoint.CorruptCheckpointError, OSError) as error:
            corrupt[path] = str(error)
    if corrupt and not configs:
        listed = "; ".join(f"{path}: {reason}" for path, reason in corrupt.items())
        raise RunDirError(f"every checkpoint of {logdir} is corrupt ({listed}); nothing was "
                          f"changed; {restart_hint(logdir)}")
    config, config_from = saved_config, None
    if config is None and configs:  # checkpoints, and no config.json
        config_from = next((path for path in reversed(configs) if configs[path]), None)
        if config_from is None:
            raise RunDirError(
                f"{logdir} has checkpoints ({', '.join(p.name for p in configs)}) but no "
                "config.json, and they were written before checkpoints held their config, so "
                "the run's config cannot be told; nothing was changed; restore config.json "
                f"from a copy of the run, or {restart_hint(logdir)}")
        config = configs[config_from]
    foreign = {}
    for path, saved in configs.items():
        changed = config_changes(config, saved) if config and saved else []
        if changed:
            more = f", and {len(changed) - 1} more" if len(changed) > 1 else ""
            foreign[path] = f"its config differs from the run's: {changed[0]}{more}"
    if configs and len(foreign) == len(configs):
        path = next(reversed(foreign))
        raise RunDirError(f"every checkpoint of {logdir} is another run's than its config.json "
                          f"says ({path.name}: {foreign[path]}); nothing was changed; "
                          f"{restart_hint(logdir)}")
    return Survey(corrupt, foreign, config, config_from)


def set_aside(ckpt_dir: Path, subdir: str, checkpoints: dict[Path, str]) -> dict[Path, Path]:
    """Move ``checkpoints`` (path -> why) to ``checkpoints/<subdir>/``, out of the kept ones
    (never overwriting a file there); returns where each went."""
    moved = {}
    for path in checkpoints:
        target = _unused(ckpt_dir / subdir / path.name)
        target.parent.mkdir(exist_ok=True)
        path.rename(target)
        moved[path] = target
    return moved


def set_aside_corrupt(ckpt_dir: Path, corrupt: dict[Path, str]) -> dict[Path, Path]:
    """Move each corrupt checkpoint (path -> what is wrong) to ``checkpoints/corrupt/`` with a
    warning; returns where they went."""
    moved = set_aside(ckpt_dir, CORRUPT_DIR, corrupt)
    for path, target in moved.items():
        warnings.warn(f"corrupt checkpoint {path} ({corrupt[path]}) moved to {target}",
                      stacklevel=3)
    return moved


def remove_interrupted_writes(*directories: Path) -> list[Path]:
    """Remove the temporary files of :func:`~vsgjax.data.checkpoint.atomic_write` (hidden
    ``.<name>.<random>.tmp``) left in ``directories`` by a process that died mid-write; only
    the lock holder calls this, so no live write is touched. Returns what was removed."""
    removed = [path for directory in directories if directory.is_dir()
               for path in sorted(directory.glob(f".*{checkpoint.TEMP_SUFFIX}"))]
    for path in removed:
        path.unlink(missing_ok=True)
    return removed


def _unused(path: Path) -> Path:
    """``path``, or ``path`` with the first free ``-<n>`` suffix when it exists."""
    candidate, n = path, 1
    while candidate.exists():
        candidate, n = path.with_name(f"{path.name}-{n}"), n + 1
    return candidate
