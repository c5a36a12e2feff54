"""Distracting backgrounds for the DeepMind Control pixel tasks (``env.background``).

A source gives one ``size x size x 3`` uint8 frame per observation: :meth:`reset` starts an
episode from the episode's ``numpy.random.Generator`` (so a seed fixes every frame) and returns
its first frame, :meth:`step` the next one. :func:`composite` pastes a frame behind the agent:

- ``video``: the user's video files (``env.background_dir``; DBC, TPC and DreamerPro use
  Kinetics-400 "driving car" videos). The files, sorted by name, split into a train half (even
  positions) and a test half (odd positions, for the evaluation envs). Each episode plays one
  video of its split from a random start frame, one frame per observation, looping at its end,
  resized to the image size. Videos are decoded in the process by OpenCV's FFmpeg (no
  subprocess: forking a process that runs JAX's threads can deadlock it), and
  :func:`check_videos` decodes the first frame of every file before a run writes anything.
- ``dots``: coloured dots on black, each moving by its law: ``bounce`` (constant velocity,
  reflected at the borders) or ``brownian`` (Gaussian increments, reflected at the borders), as
  the Distracting Control Suite's and gym-distractions' dots.
- ``noise``: i.i.d. uniform noise per pixel and observation.
- ``color``: one uniform random colour per episode.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image

from vsgjax.config.schema import ConfigError

VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".gif")
DOT_LAWS = ("bounce", "brownian")


def composite(frame: np.ndarray, background: np.ndarray) -> np.ndarray:
    """``frame`` with ``background`` where the frame is bluish (blue > red and blue > green: the
    suite's default skybox and floor, DBC's and TPC's mask); every other pixel is kept."""
    frame = np.asarray(frame)
    blue = frame[..., 2]
    mask = (blue > frame[..., 0]) & (blue > frame[..., 1])
    return np.where(mask[..., None], background, frame).astype(np.uint8)


class Color:
    """One random colour per episode."""

    def __init__(self, size: int):
        self.size = size

    def reset(self, rng: np.random.Generator) -> np.ndarray:
        colour = rng.integers(0, 256, 3, dtype=np.uint8)
        self._frame = np.broadcast_to(colour, (self.size, self.size, 3)).copy()
        return self._frame

    def step(self) -> np.ndarray:
        return self._frame


class Noise:
    """I.i.d. uniform noise in every pixel and channel, redrawn every observation."""

    def __init__(self, size: int):
        self.size = size

    def reset(self, rng: np.random.Generator) -> np.ndarray:
        self._rng = rng
        return self.step()

    def step(self) -> np.ndarray:
        return self._rng.integers(0, 256, (self.size, self.size, 3), dtype=np.uint8)


class Dots:
    """``num`` dots of radius ``radius`` (a fraction of the image side) on black.

    Positions live in the unit square, kept in ``[radius, 1 - radius]`` by reflection at the
    borders. Per episode every dot draws a colour, a start position and a law from ``laws``:
    ``bounce`` moves by a constant velocity of norm ``speed`` (its component flips at a border),
    ``brownian`` by ``N(0, speed^2)`` increments per coordinate.
    """

    def __init__(self, size: int, num: int = 12, radius: float = 0.05, speed: float = 0.03,
                 laws: tuple[str, ...] = DOT_LAWS):
        unknown = [law for law in laws if law not in DOT_LAWS]
        if not laws or unknown:
            raise ValueError(f"dot laws {laws!r}; valid: a non-empty tuple of {DOT_LAWS}")
        self.size, self.num, self.radius, self.speed, self.laws = size, num, radius, speed, laws
        centres = (np.arange(size) + 0.5) / size
        self._grid = np.stack(np.meshgrid(centres, centres, indexing="ij"), -1)  # (row, col)

    def reset(self, rng: np.random.Generator) -> np.ndarray:
        self._rng = rng
        self.colours = rng.integers(0, 256, (self.num, 3), dtype=np.uint8)
        self.positions = rng.uniform(self.radius, 1 - self.radius, (self.num, 2))
        self.brownian = np.array(self.laws)[rng.integers(len(self.laws), size=self.num)] == (
            "brownian")
        angle = rng.uniform(0, 2 * np.pi, self.num)
        self.velocities = self.speed * np.stack([np.cos(angle), np.sin(angle)], -1)
        return self._draw()

    def step(self) -> np.ndarray:
        noise = self._rng.normal(0.0, self.speed, (self.num, 2))
        moved = self.positions + np.where(self.brownian[:, None], noise, self.velocities)
        low, high = self.radius, 1 - self.radius
        below, above = moved < low, moved > high
        self.positions = np.where(below, 2 * low - moved, np.where(above, 2 * high - moved, moved))
        self.positions = np.clip(self.positions, low, high)  # a step longer than the free width
        self.velocities = np.where(below | above, -self.velocities, self.velocities)
        return self._draw()

    def _draw(self) -> np.ndarray:
        frame = np.zeros((self.size, self.size, 3), np.uint8)
        distance = np.linalg.norm(self._grid[None] - self.positions[:, None, None], axis=-1)
        for inside, colour in zip(distance <= self.radius, self.colours, strict=True):
            frame[inside] = colour
        return frame


def video_files(folder: str) -> list[Path]:
    """The video files of ``folder`` sorted by name; ConfigError naming the folder unless it
    exists and holds at least two (the train and test splits must both be non-empty)."""
    path = Path(folder).expanduser()
    if not folder or not path.is_dir():
        raise ConfigError(f"env.background_dir={folder!r} is not a folder; valid: a folder of "
                          f"video files ({', '.join(VIDEO_SUFFIXES)})")
    files = sorted(p for p in path.iterdir() if p.suffix.lower() in VIDEO_SUFFIXES)
    if len(files) < 2:
        raise ConfigError(f"env.background_dir={folder!r} holds {len(files)} video file(s) "
                          f"({', '.join(VIDEO_SUFFIXES)}); valid: at least 2, one for the train "
                          "and one for the test split")
    return files


def video_problem(path: Path) -> str | None:
    """Why the first frame of the video file ``path`` cannot be decoded (unreadable, empty,
    not a video or truncated); None when it decodes."""
    import cv2

    try:
        with open(path, "rb") as file:
            if not file.read(1):
                return "it is empty"
    except OSError as error:
        return f"it cannot be read ({error.strerror or error})"
    capture = cv2.VideoCapture(str(path))
    try:
        if not capture.isOpened():
            return "FFmpeg cannot open it (not a video, or truncated)"
        decoded, _ = capture.read()
    finally:
        capture.release()
    return None if decoded else "FFmpeg opens it but decodes no frame (damaged or truncated)"


def check_videos(folder: str) -> list[Path]:
    """:func:`video_files` of ``folder`` after decoding the first frame of every one;
    ConfigError naming the first file that does not decode and why."""
    files = video_files(folder)
    for path in files:
        problem = video_problem(path)
        if problem:
            raise ConfigError(f"env.background_dir={folder!r}: video {path.name!r} does not "
                              f"decode: {problem}; valid: a folder whose video files "
                              f"({', '.join(VIDEO_SUFFIXES)}) all decode (move or replace it)")
    return files


def split(files: list[Path], test: bool) -> list[Path]:
    """The train (even positions) or test (odd positions) half of the sorted files."""
    return files[1::2] if test else files[0::2]


def read_video(path: Path, size: int) -> np.ndarray:
    """Every frame of a video file as ``(T, size, size, 3)`` uint8 RGB (area-averaged resize),
    decoded in this process (see the module doc); frames after a damaged one are dropped."""
    import cv2

    capture = cv2.VideoCapture(str(path))
    frames = []
    try:
        while True:
            decoded, frame = capture.read()  # BGR, 3 channels (grey videos converted)
            if not decoded:
                break
            image = Image.fromarray(np.ascontiguousarray(frame[..., ::-1]))
            frames.append(np.asarray(image.resize((size, size), Image.Resampling.BOX)))
    finally:
        capture.release()
    if not frames:
        raise ValueError(f"video {str(path)!r} has no frame that decodes")
    return np.stack(frames)


class Video:
    """Videos of one split: a random video and start frame per episode, one frame per step,
    looping at the video's end. The last video read is kept decoded."""

    def __init__(self, size: int, files: list[Path]):
        self.size, self.files = size, files
        self._loaded: tuple[Path, np.ndarray] | None = None

    def reset(self, rng: np.random.Generator) -> np.ndarray:
        path = self.files[rng.integers(len(self.files))]
        if self._loaded is None or self._loaded[0] != path:
            self._loaded = path, read_video(path, self.size)
        self.video = path
        self.frame_index = int(rng.integers(len(self._loaded[1])))
        return self._loaded[1][self.frame_index]

    def step(self) -> np.ndarray:
        frames = self._loaded[1]
        self.frame_index = (self.frame_index + 1) % len(frames)
        return frames[self.frame_index]


def make_background(kind: str, size: int, folder: str = "", test: bool = False):
    """The source ``kind`` (``env.background``; None for ``none``), with the ``test`` split of
    ``folder``'s videos for evaluation envs and the train split otherwise."""
    if kind == "none":
        return None
    if kind == "video":
        return Video(size, split(video_files(folder), test))
    sources = {"dots": Dots, "noise": Noise, "color": Color}
    if kind not in sources:
        raise ConfigError(f"env.background={kind!r}; valid: none, video, "
                          + ", ".join(sources))
    return sources[kind](size)
