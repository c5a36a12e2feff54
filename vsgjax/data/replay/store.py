"""Episodes on disk: one MCAP file per episode, one channel per key, images viewable in Foxglove.

An *episode* is a dict of numpy arrays sharing the leading time dimension T (the sequence-batch
format of the project without the batch dimension)::

    image        uint8   [T, H, W, C]  C = 3 (RGB) or 1 (grayscale); absent in vector tasks
    action       float32 [T, A]        action that led to obs t (zeros at t = 0)
    reward       float32 [T]           reward on arriving at obs t (0 at t = 0)
    is_first     bool    [T]           True exactly at t = 0
    is_terminal  bool    [T]           may be True only at t = T - 1
    <extra key>  any bool/int/float dtype, [T, ...]   (e.g. discovery metrics, step ids)

MCAP schema (version 1)
-----------------------
* File name ``<UTC yyyymmddTHHMMSSffffff>-<8 hex>-<T>.mcap``, or ``e<12-digit number>-<T>.mcap``
  (the run's episode number; the device loop, whose resume rewrites the episodes after its
  checkpoint): names sort chronologically.
* Chunks compressed with zstd (lossless; Foxglove reads them), chunk CRCs written and checked.
* Metadata record ``vsgjax.episode``: ``{"version": "1", "length": "<T>",
  "keys": "<JSON list of keys>"}``.
* One channel per key, topic ``/<key>``, message encoding ``json``, channel metadata
  ``{"dtype": "<numpy dtype name>", "shape": "<JSON list: per-step shape>"}``.
  Step t is the message with ``sequence = t`` and ``log_time = publish_time = t * 50 ms``
  (a nominal 20 Hz clock so Foxglove plays an episode back at a watchable speed).
* ``/image``: schema ``foxglove.RawImage`` (encoding ``jsonschema``), one message per step::

      {"timestamp": {"sec": s, "nsec": ns}, "frame_id": "camera", "width": W, "height": H,
       "encoding": "rgb8" | "mono8", "step": W * C, "data": "<base64 of the H*W*C bytes>"}

  Raw, lossless uint8 pixels, row-major. Open the file in Foxglove and add an Image panel.
* every other key: schema ``vsgjax.<key>`` (encoding ``jsonschema``), messages
  ``{"value": v}`` where v is the step's value as JSON (a number/boolean, or nested lists for
  per-step arrays). float32 values round-trip exactly (float32 -> float64 repr -> float32).
  Foxglove's Plot panel shows e.g. ``/reward.value`` or ``/action.value[0]``.

Raw pixels in zstd chunks rather than PNG, and JSON for the small channels, keep every
channel readable by Foxglove and any JSON parser (docs/replay-and-checkpoints.md compares).

Crash safety: a file is built in memory and written with ``vsgjax.data.checkpoint.atomic_write``
(hidden temp file in the same directory, fsync, ``os.replace``), so a ``*.mcap`` name only
ever holds a complete file; temp files left by a crash (``.*.tmp``) are never read.  Reading
validates the MCAP structure, the chunk CRCs and the episode (every key present with exactly
one message per step); a file failing any check is skipped with a ``warnings.warn`` naming it.
"""

from __future__ import annotations

import base64
import datetime
import io
import json
import os
import uuid
import warnings
from collections.abc import Mapping
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from vsgjax.data.checkpoint import atomic_write
from vsgjax.episode_keys import EPISODE_DTYPES, IMAGE_KEY

SCHEMA_VERSION = "1"
EPISODE_METADATA = "vsgjax.episode"
STEP_NS = 50_000_000  # nominal time between steps in the file (20 Hz)
NUMBERED_PREFIX = "e"  # sorts after the time-named files ("2...") of an older run
_IMAGE_ENCODINGS = {1: "mono8", 3: "rgb8"}
_RAW_IMAGE_SCHEMA = {
    "title": "foxglove.RawImage",
    "description": "A raw image",
    "type": "object",
    "properties": {
        "timestamp": {
            "type": "object",
            "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}},
        },
        "frame_id": {"type": "string"},
        "width": {"type": "integer"},
        "height": {"type": "integer"},
        "encoding": {"type": "string"},
        "step": {"type": "integer"},
        "data": {"type": "string", "contentEncoding": "base64"},
    },
}


class CorruptEpisodeError(ValueError):
    """An MCAP file that is readable but does not hold a complete, consistent episode."""


def episode_length(episode: Mapping[str, np.ndarray]) -> int:
    """Check ``episode`` against the episode format (see module docstring); return T."""
    for key, value in episode.items():
        if not isinstance(value, np.ndarray) or value.dtype.kind not in "biuf" or value.ndim < 1:
            raise ValueError(f"episode[{key!r}] must be a bool/int/float numpy array with a time "
                             f"axis, got {type(value).__name__} {getattr(value, 'dtype', '')}")
    for key, (dtype, ndim) in EPISODE_DTYPES.items():
        if key not in episode:
            raise ValueError(f"episode lacks key {key!r}; has {sorted(episode)}")
        value = episode[key]
        if value.dtype != dtype or value.ndim != ndim:
            raise ValueError(f"episode[{key!r}] must be a {dtype} array of rank {ndim}, "
                             f"got {value.dtype}{list(value.shape)}")
    lengths = {key: len(value) for key, value in episode.items()}
    length = lengths["is_first"]
    if length < 1 or any(n != length for n in lengths.values()):
        raise ValueError(f"episode arrays need one shared length >= 1, got lengths {lengths}")
    image = episode.get(IMAGE_KEY)
    if image is not None and (image.dtype != np.uint8 or image.ndim != 4):
        raise ValueError(f"episode['image'] must be a uint8 array of rank 4, got "
                         f"{image.dtype}{list(image.shape)}")
    if image is not None and image.shape[-1] not in _IMAGE_ENCODINGS:
        raise ValueError(f"episode images need 1 or 3 channels, got shape {episode['image'].shape}")
    first = episode["is_first"]
    if not first[0] or first[1:].any():
        raise ValueError(
            f"is_first must be True exactly at t=0, got True at {np.flatnonzero(first).tolist()}"
        )
    if episode["is_terminal"][:-1].any():
        raise ValueError("is_terminal may only be True at the last step of an episode")
    return length


def encode_episode(episode: Mapping[str, np.ndarray]) -> bytes:
    """The bytes of the MCAP file of one episode (format in the module docstring)."""
    length = episode_length(episode)
    buffer = io.BytesIO()
    writer = Writer(buffer, compression=CompressionType.ZSTD)
    writer.start(profile="", library="vsgjax")
    writer.add_metadata(
        EPISODE_METADATA,
        {"version": SCHEMA_VERSION, "length": str(length), "keys": json.dumps(list(episode))},
    )
    for key, value in episode.items():
        channel = _register(writer, key, value)
        if key == IMAGE_KEY:
            payloads = [_encode_image(frame, t * STEP_NS) for t, frame in enumerate(value)]
        else:
            payloads = [json.dumps({"value": step}).encode() for step in value.tolist()]
        for t, payload in enumerate(payloads):
            writer.add_message(channel, t * STEP_NS, payload, t * STEP_NS, t)
    writer.finish()
    return buffer.getvalue()


def _register(writer: Writer, key: str, value: np.ndarray) -> int:
    if key == IMAGE_KEY:
        schema = writer.register_schema(
            "foxglove.RawImage", "jsonschema", json.dumps(_RAW_IMAGE_SCHEMA).encode()
        )
    else:
        value_schema = {"title": f"vsgjax.{key}", "type": "object",
                        "properties": {"value": _json_type(value.dtype, value.ndim - 1)}}
        schema = writer.register_schema(
            f"vsgjax.{key}", "jsonschema", json.dumps(value_schema).encode()
        )
    metadata = {"dtype": value.dtype.name, "shape": json.dumps(list(value.shape[1:]))}
    return writer.register_channel(f"/{key}", "json", schema, metadata)


def _json_type(dtype: np.dtype, ndim: int) -> dict:
    kind = {"b": "boolean", "i": "integer", "u": "integer", "f": "number"}[dtype.kind]
    schema = {"type": kind}
    for _ in range(ndim):
        schema = {"type": "array", "items": schema}
    return schema


def _encode_image(frame: np.ndarray, time_ns: int) -> bytes:
    """The foxglove.RawImage JSON message of one [H, W, C] uint8 frame."""
    height, width, channels = frame.shape
    data = base64.b64encode(frame.tobytes())
    sec, nsec = divmod(time_ns, 1_000_000_000)
    # Base64 needs no JSON escaping, so the message is formatted directly (json.dumps of a
    # 16 kB string costs more than the rest of the write).
    return (
        b'{"timestamp":{"sec":%d,"nsec":%d},"frame_id":"camera","width":%d,"height":%d,'
        b'"encoding":"%s","step":%d,"data":"%s"}'
        % (sec, nsec, width, height, _IMAGE_ENCODINGS[channels].encode(), width * channels, data)
    )


def decode_episode(data: bytes) -> dict[str, np.ndarray]:
    """Inverse of :func:`encode_episode`; raises on any structural or consistency problem."""
    reader = make_reader(io.BytesIO(data), validate_crcs=True)
    metadata = [m for m in reader.iter_metadata() if m.name == EPISODE_METADATA]
    if len(metadata) != 1 or metadata[0].metadata.get("version") != SCHEMA_VERSION:
        raise CorruptEpisodeError(f"no {EPISODE_METADATA} metadata of version {SCHEMA_VERSION}")
    length = int(metadata[0].metadata["length"])
    keys = json.loads(metadata[0].metadata["keys"])
    channels = {channel.topic: channel for channel in reader.get_summary().channels.values()}
    messages: dict[str, list[bytes | None]] = {f"/{key}": [None] * length for key in keys}
    for _, channel, message in reader.iter_messages(log_time_order=False):
        steps = messages.get(channel.topic)
        if steps is None or not 0 <= message.sequence < length or steps[message.sequence]:
            raise CorruptEpisodeError(
                f"unexpected message on {channel.topic} with sequence {message.sequence}"
            )
        steps[message.sequence] = message.data
    episode = {}
    for key in keys:
        steps = messages[f"/{key}"]
        missing = [t for t, step in enumerate(steps) if step is None]
        if missing:
            raise CorruptEpisodeError(f"channel /{key} lacks steps {missing[:10]}")
        shape = (length, *json.loads(channels[f"/{key}"].metadata["shape"]))
        dtype = np.dtype(channels[f"/{key}"].metadata["dtype"])
        # One json.loads per channel (a JSON list of all its messages) is several times faster
        # than one per message.
        decoded = json.loads(b"[" + b",".join(steps) + b"]")
        if key == IMAGE_KEY:
            pixels = b"".join(base64.b64decode(step["data"]) for step in decoded)
            episode[key] = np.frombuffer(pixels, dtype).reshape(shape).copy()
        else:
            episode[key] = np.array([step["value"] for step in decoded], dtype).reshape(shape)
    episode_length(episode)
    return episode


def read_episode(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read one episode file; raises if it is corrupt (see :meth:`EpisodeStore.load`)."""
    return decode_episode(Path(path).read_bytes())


class EpisodeStore:
    """A directory of episode MCAP files (created if missing)."""

    def __init__(self, directory: str | os.PathLike):
        self.directory = Path(directory)
        self.directory.mkdir(parents=True, exist_ok=True)

    def write(self, episode: Mapping[str, np.ndarray], number: int | None = None) -> Path:
        """Atomically write ``episode``; return its path. The file is new, named by the time,
        or, given its ``number`` in the run, ``e<number>-<T>.mcap``, which a rewrite of the
        same episode replaces."""
        data = encode_episode(episode)
        if number is None:
            stamp = datetime.datetime.now(datetime.UTC).strftime("%Y%m%dT%H%M%S%f")
            stem = f"{stamp}-{uuid.uuid4().hex[:8]}"
        else:
            stem = f"{NUMBERED_PREFIX}{number:012d}"
        return atomic_write(self.directory / f"{stem}-{len(episode['is_first'])}.mcap", data)

    def paths(self) -> list[Path]:
        """Every episode file, oldest first (temp files of interrupted writes excluded)."""
        return sorted(self.directory.glob("*.mcap"))

    def load(self, limit_steps: int | None = None) -> list[dict[str, np.ndarray]]:
        """Read episodes newest first until the next one would exceed ``limit_steps`` steps.

        Returns them oldest first (the order to add them to a :class:`Replay`, which evicts
        oldest first).  ``None`` loads every episode.  Corrupt or truncated files are skipped
        with a warning naming the file.
        """
        episodes, total = [], 0
        for path in reversed(self.paths()):
            try:
                episode = read_episode(path)
            except Exception as error:  # any failure to parse a file on disk means corrupt
                warnings.warn(
                    f"skipping corrupt episode file {path}: {type(error).__name__}: {error}",
                    stacklevel=2,
                )
                continue
            length = len(episode["is_first"])
            if limit_steps is not None and total + length > limit_steps:
                break
            episodes.append(episode)
            total += length
        return episodes[::-1]
