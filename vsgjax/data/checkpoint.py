"""Checkpoints: atomic save/restore of a pytree of arrays plus a JSON-able dict of counters.

One checkpoint is one file ``<dir>/ckpt-<step:012d>.ckpt``::

    b"VSGJAXCK"                 8-byte magic
    format version              uint32 little endian (currently 1)
    payload length              uint64 little endian
    payload CRC-32              uint32 little endian (zlib.crc32 of the payload)
    payload                     msgpack (flax.serialization.msgpack_serialize) of
                                {"meta": <JSON text>, "paths": [str],
                                 "leaves": {"0": ndarray, "1": ndarray, ...}}

``paths`` are the ``jax.tree_util.keystr`` of every leaf of the saved pytree in flattening
order; restoring flattens a *target* pytree of the same structure (params, optimizer states,
slow critic, jax PRNG keys as uint32 arrays ...) and fills it leaf by leaf, checking that paths,
shapes and dtypes agree.  ``meta`` carries counters and host RNG state (see :func:`rng_state`).

Why msgpack and not orbax: a checkpoint here is a few hundred MB at most and written by one
process, so one self-checking file written with :func:`atomic_write` (temp file in the same
directory, fsync, ``os.replace``, fsync of the directory) gives atomicity and corruption
detection with no background threads, directory renames or extra dependencies.

Atomicity and fallback: a crash while saving leaves at most a hidden ``.ckpt-*.tmp`` file,
never a partial ``.ckpt``.  :func:`restore` tries checkpoints newest first; a file with a bad
magic, length or CRC is reported with ``warnings.warn`` and the previous one is used.
A checkpoint that is intact but does not fit the target is an error naming it (another run's
checkpoint, or a changed config), not a reason to fall back silently.
"""

from __future__ import annotations

import io
import json
import os
import re
import struct
import tempfile
import warnings
import zlib
from pathlib import Path
from typing import Any, NamedTuple

import jax
import msgpack
import numpy as np
from flax import serialization

MAGIC = b"VSGJAXCK"
FORMAT_VERSION = 1
_HEADER = struct.Struct("<8sIQI")  # magic, version, payload length, payload crc32
_NAME = re.compile(r"^ckpt-(\d+)\.ckpt$")
TEMP_SUFFIX = ".tmp"  # atomic_write's hidden temporary file: .<name>.<random>.tmp


class CorruptCheckpointError(ValueError):
    """A checkpoint file that is truncated, overwritten or not a checkpoint at all."""


class CheckpointMismatchError(ValueError):
    """An intact checkpoint whose tree does not match the restore target: ``reason`` says
    where; ``path`` and ``step`` name the checkpoint (when restored from a directory)."""

    def __init__(self, reason: str, path: Path | None = None, step: int | None = None):
        message = reason if path is None else (
            f"checkpoint {path} does not fit this run ({reason}); is it another run's? move it "
            "out of the run's checkpoints/")
        super().__init__(message)
        self.reason, self.path, self.step = reason, path, step


class WriteError(OSError):
    """A file that could not be written (disk full, read-only, ...); the previous one stays."""


class Checkpoint(NamedTuple):
    step: int
    tree: Any
    meta: dict
    path: Path


def atomic_write(path: str | os.PathLike, data: bytes) -> Path:
    """Write ``data`` to ``path`` so that readers see either the old file or all of ``data``.

    The bytes go to a hidden temp file in the same directory (same filesystem, so the rename
    is atomic), which is fsynced and renamed over ``path``; the directory is fsynced so the
    rename itself survives a power loss.  On any error the temp file is removed and ``path``
    is left as it was; an OSError is raised as :class:`WriteError` naming ``path``.
    """
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=TEMP_SUFFIX)
    except OSError as error:
        raise WriteError(f"cannot write {path}: {error.strerror}") from error
    try:
        with os.fdopen(fd, "wb") as file:
            file.write(data)
            file.flush()
            os.fsync(file.fileno())
        os.replace(tmp, path)
    except BaseException as error:
        Path(tmp).unlink(missing_ok=True)
        if isinstance(error, OSError):
            raise WriteError(f"cannot write {path}: {error.strerror}; the file is as it was "
                             "before") from error
        raise
    dir_fd = os.open(path.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)
    return path


def checkpoint_path(directory: str | os.PathLike, step: int) -> Path:
    return Path(directory) / f"ckpt-{step:012d}.ckpt"


def list_checkpoints(directory: str | os.PathLike) -> list[tuple[int, Path]]:
    """(step, path) of every checkpoint file in ``directory``, oldest first (unvalidated)."""
    directory = Path(directory)
    if not directory.is_dir():
        return []
    found = [(int(m.group(1)), p) for p in directory.iterdir() if (m := _NAME.match(p.name))]
    return sorted(found)


def latest(directory: str | os.PathLike) -> Path | None:
    """Path of the checkpoint with the highest step, or None (the file is not validated)."""
    found = list_checkpoints(directory)
    return found[-1][1] if found else None


def save(
    directory: str | os.PathLike, step: int, tree: Any, meta: dict | None = None, keep: int = 3
) -> Path:
    """Atomically write ``tree`` and ``meta`` as the checkpoint of ``step``; keep the last ``keep``.

    Checkpoints of later steps than ``step`` belong to an abandoned timeline (for example a
    corrupt checkpoint that :func:`restore` skipped) and are deleted, so the next restore
    continues from this one.

    ``meta`` must be JSON-serialisable (counters, :func:`rng_state` dicts, ...).
    Leaves may be jax or numpy arrays or Python scalars; typed jax keys (``jax.random.key``)
    must be converted with ``jax.random.key_data`` first.
    """
    if keep < 1:
        raise ValueError(f"keep must be >= 1, got {keep}")
    if step < 0:
        raise ValueError(f"step must be >= 0, got {step}")
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    path = atomic_write(checkpoint_path(directory, step), encode(tree, meta or {}))
    checkpoints = list_checkpoints(directory)
    newer = [old for old_step, old in checkpoints if old_step > step]
    older = [old for old_step, old in checkpoints if old_step < step]
    for old in newer + older[: max(0, len(older) - keep + 1)]:
        old.unlink(missing_ok=True)
    return path


def encode(tree: Any, meta: dict) -> bytes:
    """The bytes of one checkpoint file (header + msgpack payload)."""
    leaves_with_paths, _ = jax.tree_util.tree_flatten_with_path(tree)
    paths = [jax.tree_util.keystr(path) for path, _ in leaves_with_paths]
    # A dict (not a list) of leaves: flax only splits arrays above 2**30 bytes inside dicts.
    leaves = {
        str(i): _to_numpy(path, leaf)
        for i, (path, (_, leaf)) in enumerate(zip(paths, leaves_with_paths, strict=True))
    }
    payload = serialization.msgpack_serialize(
        {"meta": json.dumps(meta), "paths": paths, "leaves": leaves}
    )
    header = _HEADER.pack(MAGIC, FORMAT_VERSION, len(payload), zlib.crc32(payload))
    return header + payload


def _to_numpy(path: str, leaf: Any) -> np.ndarray:
    if isinstance(leaf, jax.Array) and jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
        raise TypeError(
            f"leaf {path} is a typed PRNG key array; save jax.random.key_data(key) instead"
        )
    return np.asarray(jax.device_get(leaf))


def decode(data: bytes, target: Any, partial: bool = False) -> tuple[Any, dict]:
    """Inverse of :func:`encode`: fill ``target``'s structure with the saved leaves (with
    ``partial``, those at the target's paths: :func:`_fill`)."""
    content = serialization.msgpack_restore(_payload(data))
    return (_fill(target, content["paths"], content["leaves"], partial),
            json.loads(content["meta"]))


def verify(path: str | os.PathLike) -> None:
    """Raise CorruptCheckpointError (or OSError) unless ``path``'s header and CRC are intact."""
    _payload(Path(path).read_bytes())


def read_meta(path: str | os.PathLike) -> dict:
    """The ``meta`` of one checkpoint file, after checking its header and CRC, without
    decoding its arrays; raises CorruptCheckpointError (or OSError)."""
    payload = _payload(Path(path).read_bytes())
    # msgpack stores the payload's keys sorted ("leaves" before "meta"): the leaves are
    # skipped unread, each of them held in the unpacker's buffer at most once
    unpacker = msgpack.Unpacker(io.BytesIO(payload), raw=False, max_buffer_size=len(payload))
    try:
        for _ in range(unpacker.read_map_header()):
            if unpacker.unpack() == "meta":
                return json.loads(unpacker.unpack())
            unpacker.skip()
    except (ValueError, msgpack.UnpackException) as error:
        raise CorruptCheckpointError(f"unreadable payload ({error})") from None
    raise CorruptCheckpointError("the payload holds no meta")


def _payload(data: bytes) -> bytes:
    """The payload of a checkpoint file's bytes, after checking header, length and CRC."""
    if len(data) < _HEADER.size:
        raise CorruptCheckpointError(f"{len(data)} bytes is shorter than the header")
    magic, version, length, crc = _HEADER.unpack_from(data)
    payload = data[_HEADER.size:]
    if magic != MAGIC:
        raise CorruptCheckpointError(f"bad magic {magic!r}")
    if version != FORMAT_VERSION:
        raise CorruptCheckpointError(f"unknown format version {version}")
    if len(payload) != length:
        raise CorruptCheckpointError(f"payload has {len(payload)} bytes, header says {length}")
    if zlib.crc32(payload) != crc:
        raise CorruptCheckpointError("payload CRC-32 mismatch")
    return payload


def _fill(target: Any, paths: list[str], leaves: dict[str, Any], partial: bool = False) -> Any:
    """Rebuild ``target``'s tree from saved leaves; leaves take the target leaves' types.

    With ``partial`` the target may leave subtrees out (``None`` in their place): only the
    saved leaves at the target's paths are read, and every target path must be saved.
    """
    target_with_paths, treedef = jax.tree_util.tree_flatten_with_path(target)
    target_paths = [jax.tree_util.keystr(path) for path, _ in target_with_paths]
    if partial:
        wanted = set(target_paths)
        kept = [i for i, path in enumerate(paths) if path in wanted]
        paths = [paths[i] for i in kept]
        leaves = {str(j): leaves[str(i)] for j, i in enumerate(kept)}
    if target_paths != list(paths):
        pairs = zip(target_paths, paths, strict=False)  # the shorter list's length
        first = next((i for i, (a, b) in enumerate(pairs) if a != b),
                     min(len(paths), len(target_paths)))
        saved = paths[first] if first < len(paths) else "none"
        wanted = target_paths[first] if first < len(target_paths) else "none"
        raise CheckpointMismatchError(
            f"its tree is not this run's: {len(paths)} saved leaves, {len(target_paths)} "
            f"wanted; leaf {first} is {saved}, wanted {wanted}"
        )
    filled = [
        _like(path, leaves[str(i)], like)
        for i, (path, (_, like)) in enumerate(zip(paths, target_with_paths, strict=True))
    ]
    return jax.tree_util.tree_unflatten(treedef, filled)


def _like(path: str, value: Any, like: Any) -> Any:
    value = np.asarray(value)
    if isinstance(like, bool | int | float):
        return type(like)(value.item())
    shape, dtype = np.shape(like), np.dtype(like.dtype)
    if value.shape != shape or value.dtype != dtype:
        raise CheckpointMismatchError(
            f"leaf {path}: checkpoint has {value.dtype}{list(value.shape)}, "
            f"target wants {dtype}{list(shape)}"
        )
    wants_jax = isinstance(like, jax.Array | jax.ShapeDtypeStruct)  # a struct: shapes-only target
    return jax.numpy.asarray(value) if wants_jax else value


def load(path: str | os.PathLike, target: Any, partial: bool = False) -> tuple[Any, dict]:
    """Read one checkpoint file into ``target``'s structure (all of it, or with ``partial``
    the part the target names); raises CorruptCheckpointError."""
    return decode(Path(path).read_bytes(), target, partial)


def restore(directory: str | os.PathLike, target: Any, max_step: int | None = None,
            partial: bool = False) -> Checkpoint | None:
    """The newest readable checkpoint in ``directory`` filled into ``target``, or None if none;
    with ``max_step``, the newest of a step up to it; with ``partial``, only the saved leaves
    at the target's paths (a target with ``None`` for the subtrees it leaves out).

    Corrupt files are skipped with a warning naming them, falling back to older checkpoints.
    """
    for step, path in reversed(list_checkpoints(directory)):
        if max_step is not None and step > max_step:
            continue
        try:
            tree, meta = load(path, target, partial)
        except (CorruptCheckpointError, OSError) as error:
            warnings.warn(
                f"skipping corrupt checkpoint {path}: {type(error).__name__}: {error}",
                stacklevel=2,
            )
            continue
        except CheckpointMismatchError as error:
            raise CheckpointMismatchError(error.reason, path, step) from None
        return Checkpoint(step=step, tree=tree, meta=meta, path=path)
    return None


def rng_state(rng: np.random.Generator) -> dict:
    """JSON-able state of a numpy Generator (for a checkpoint's ``meta``)."""
    return rng.bit_generator.state


def rng_from_state(state: dict) -> np.random.Generator:
    """A numpy Generator that continues exactly where the one that gave ``state`` stopped."""
    name = state["bit_generator"]
    bit_generator_cls = getattr(np.random, name, None)
    if bit_generator_cls is None or not issubclass(bit_generator_cls, np.random.BitGenerator):
        raise ValueError(f"unknown numpy bit generator {name!r} in RNG state")
    bit_generator = bit_generator_cls()
    bit_generator.state = state
    return np.random.Generator(bit_generator)

