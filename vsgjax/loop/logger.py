"""Run logging: ``metrics.jsonl``, TensorBoard events, videos and the progress bar.

Every record is keyed by the env step (counting action repeat). ``metrics.jsonl`` holds one JSON
object per line, ``{"step": int, "<prefix>/<name>": float, ...}``; on resume, records written
after the checkpoint's step by the interrupted run are dropped so the file stays monotonic.
"""

from __future__ import annotations

import json
import math
import os
import time
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import imageio.v3 as imageio
import numpy as np
from tensorboardX import SummaryWriter
from tqdm import tqdm

from vsgjax.data.checkpoint import atomic_write


def truncate_metrics(path: Path, max_step: int) -> int:
    """Drop the records of ``path`` whose step exceeds ``max_step``, and a line that is not
    JSON (the last line of a killed run, cut short) with a warning naming the file, the line
    and its text; returns how many remain."""
    if not path.exists():
        return 0
    kept = []
    for number, line in enumerate(path.read_text().splitlines(), 1):
        try:
            record = json.loads(line)
        except json.JSONDecodeError:
            shown = line if len(line) <= 80 else f"{line[:80]}..."
            warnings.warn(f"{path}, line {number}: dropped a record cut short by a killed run "
                          f"({len(line)} characters: {shown!r})", stacklevel=2)
            continue
        if record.get("step", 0) <= max_step:
            kept.append(line)
    tmp = path.with_suffix(".tmp")
    tmp.write_text("".join(f"{line}\n" for line in kept))
    os.replace(tmp, path)
    return len(kept)


def to_python(value):
    """A JSON-friendly scalar from a numpy / jax scalar or 0-d array."""
    array = np.asarray(value)
    if array.size != 1:
        raise ValueError(f"metric must be a scalar, got shape {array.shape}")
    item = array.reshape(()).item()
    return item if isinstance(item, (bool, int)) else float(item)


class Logger:
    """Writes scalar records to ``metrics.jsonl`` and TensorBoard, videos to ``videos/``."""

    def __init__(self, logdir: str | Path, resume_step: int | None = None, *,
                 metrics_file: str = "metrics.jsonl", video_dir: str = "videos"):
        self.logdir = Path(logdir)
        self.video_dir = self.logdir / video_dir
        self.video_dir.mkdir(parents=True, exist_ok=True)
        self.metrics_path = self.logdir / metrics_file
        if resume_step is not None:
            truncate_metrics(self.metrics_path, resume_step)
        self._file = open(self.metrics_path, "a")
        # purge_step: TensorBoard hides the events an interrupted run wrote after resume_step
        self._writer = SummaryWriter(str(self.logdir), flush_secs=30, purge_step=resume_step)

    def scalars(self, step: int, metrics: Mapping[str, object], prefix: str = "") -> dict:
        """Log scalars under ``prefix/name``; returns the record that was written."""
        record = {"step": int(step)}
        for name, value in metrics.items():
            key = f"{prefix}/{name}" if prefix else name
            value = to_python(value)
            finite = math.isfinite(value)
            record[key] = value if finite else None  # JSON has no NaN; null marks it
            if finite:
                self._writer.add_scalar(key, value, int(step))
        self._file.write(json.dumps(record) + "\n")
        self._file.flush()
        return record

    def video(self, name: str, step: int, frames: np.ndarray, fps: int = 20) -> Path:
        """Write ``frames`` ``[T, H, W, C]`` uint8 (C = 1 or 3) as ``videos/<name>_<step>.mp4``."""
        frames = np.asarray(frames)
        if frames.ndim != 4 or frames.dtype != np.uint8:
            raise ValueError(f"video wants uint8 [T,H,W,C], got {frames.dtype} {frames.shape}")
        if frames.shape[-1] == 1:
            frames = np.repeat(frames, 3, axis=-1)
        path = self.video_dir / f"{name}_{int(step):09d}.mp4"
        with warnings.catch_warnings():  # ffmpeg runs via fork+exec, which is safe under JAX
            warnings.filterwarnings("ignore", "os.fork", RuntimeWarning)
            data = imageio.imwrite("<bytes>", frames, extension=".mp4", fps=fps,
                                   macro_block_size=16)
        atomic_write(path, data)  # a killed run leaves the old file or none, never half of one
        self._writer.add_image(name, frames[len(frames) // 2], int(step), dataformats="HWC")
        return path

    def close(self) -> None:
        self._file.close()
        self._writer.close()


class Progress:
    """A tqdm bar over env steps showing steps/s, ETA, the latest losses and the latest return."""

    def __init__(self, total: int, initial: int, enabled: bool = True):
        self.enabled = enabled
        self._bar = tqdm(total=total, initial=initial, unit="step", dynamic_ncols=True,
                         disable=not enabled, smoothing=0.05, mininterval=1.0)
        self._fields: dict[str, str] = {}
        self._last_refresh = 0.0

    def update(self, env_steps: int) -> None:
        self._bar.update(env_steps - self._bar.n)

    def show(self, values: Mapping[str, float | Sequence[float]]) -> None:
        """Remember the values shown after the bar (several seeds' values ``/`` apart, ``-``
        for none yet); refresh it at most once a second."""
        for name, value in values.items():
            value = value if isinstance(value, Sequence) else [value]
            self._fields[name] = "/".join("-" if math.isnan(v) else f"{v:.3g}" for v in value)
        now = time.monotonic()
        if now - self._last_refresh > 1.0:
            self._bar.set_postfix(self._fields, refresh=True)
            self._last_refresh = now

    def write(self, message: str) -> None:
        self._bar.write(message)

    def close(self) -> None:
        self._bar.close()
