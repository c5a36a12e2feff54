"""Replay benchmark: MCAP episode write/read time and size, sequence sampling time, memory/frame,
and the save/restore time of a 120 MB checkpoint.

Episodes of 751 steps (one BringBackShapes episode: 3000 env steps / action repeat 4) of
64x64x3 frames, two kinds of images: "shapes" (flat background and moving coloured discs, like
BBS) and "noise" (uniform random pixels: incompressible, the worst case for size and time).
The chosen image encoding (foxglove.RawImage, raw pixels, zstd chunks) is compared with PNG in
a foxglove.CompressedImage channel written through the same MCAP writer.  No JAX code runs
here, so there is no compilation to exclude.  Run: ``python -m experiments.bench.bench_replay``.
"""

from __future__ import annotations

import base64
import io
import json
import statistics
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from vsgjax.data import checkpoint
from vsgjax.data.replay import EpisodeStore, Replay, decode_episode, encode_episode
from vsgjax.data.replay.store import _encode_image as encode_raw_image  # the chosen message format

STEPS = 751
ACTION_DIM = 2
RUNS = 5
BATCH, LENGTH = 16, 50
RESULTS = Path(__file__).parent / "results" / "replay.md"


def shapes_frames(steps: int, rng: np.random.Generator) -> np.ndarray:
    """BBS-like frames: a flat arena with five coloured discs drifting across it."""
    positions = rng.uniform(8, 56, (5, 2))
    velocities = rng.normal(0, 0.7, (5, 2))
    colours = rng.integers(40, 255, (5, 3))
    frames = np.empty((steps, 64, 64, 3), np.uint8)
    for t in range(steps):
        frame = np.full((64, 64, 3), (90, 110, 90), np.uint8)
        for (x, y), colour in zip((positions + t * velocities) % 64, colours, strict=True):
            cv2.circle(frame, (int(x), int(y)), 5, colour.tolist(), -1)
        frames[t] = frame
    return frames


def make_episode(frames: np.ndarray, rng: np.random.Generator) -> dict[str, np.ndarray]:
    steps = len(frames)
    action = rng.uniform(-1, 1, (steps, ACTION_DIM)).astype(np.float32)
    action[0] = 0
    reward = (rng.random(steps) < 0.01).astype(np.float32)
    reward[0] = 0
    return {
        "image": frames,
        "action": action,
        "reward": reward,
        "is_first": np.arange(steps) == 0,
        "is_terminal": np.zeros(steps, bool),
    }


def timed(function, runs: int = RUNS, scale: float = 1e3) -> str:
    """Median wall time and median CPU time of this process, formatted "wall (cpu)".

    On a shared machine the CPU time is the better estimate of the uncontended cost (it leaves
    out waiting for the CPU, and also the fsync waits of a write).
    """
    walls, cpus = [], []
    for _ in range(runs):
        wall, cpu = time.perf_counter(), time.process_time()
        function()
        walls.append(time.perf_counter() - wall)
        cpus.append(time.process_time() - cpu)
    wall, cpu = statistics.median(walls) * scale, statistics.median(cpus) * scale
    digits = 2 if scale == 1 else 1
    return f"{wall:.{digits}f} ({cpu:.{digits}f})"


def png_message(frame: np.ndarray, time_ns: int) -> bytes:
    """A foxglove.CompressedImage JSON message holding the frame as PNG (the alternative)."""
    png = cv2.imencode(".png", frame[:, :, ::-1])[1].tobytes()
    return b'{"frame_id":"camera","format":"png","data":"%s"}' % base64.b64encode(png)


def png_frame(message: bytes) -> np.ndarray:
    png = np.frombuffer(base64.b64decode(json.loads(message)["data"]), np.uint8)
    return cv2.imdecode(png, cv2.IMREAD_UNCHANGED)[:, :, ::-1]


def raw_frame(message: bytes) -> np.ndarray:
    pixels = np.frombuffer(base64.b64decode(json.loads(message)["data"]), np.uint8)
    return pixels.reshape(64, 64, 3)


def image_mcap(frames: np.ndarray, encode_frame) -> bytes:
    """An MCAP file holding only an image channel, one message per frame."""
    buffer = io.BytesIO()
    writer = Writer(buffer, compression=CompressionType.ZSTD)
    writer.start()
    schema = writer.register_schema("image", "jsonschema", b"{}")
    channel = writer.register_channel("/image", "json", schema)
    for t, frame in enumerate(frames):
        writer.add_message(channel, t, encode_frame(frame, t), t, t)
    writer.finish()
    return buffer.getvalue()


def read_images(data: bytes, decode_frame) -> np.ndarray:
    messages = make_reader(io.BytesIO(data)).iter_messages(log_time_order=False)
    return np.stack([decode_frame(message.data) for _, _, message in messages])


def file_rows(episodes: dict[str, dict[str, np.ndarray]], directory: Path) -> list[str]:
    store = EpisodeStore(directory)
    rows = []
    for name, episode in episodes.items():
        data = encode_episode(episode)
        write = timed(lambda episode=episode: store.write(episode))
        read = timed(lambda data=data: decode_episode(data))
        rows.append(f"| {name} | {write} | {read} | "
                    f"{len(data) / 1e6:.2f} | {len(data) / STEPS:,.0f} |")
    return rows


def encoding_rows(frames_by_kind: dict[str, np.ndarray]) -> list[str]:
    rows = []
    encodings = [("RawImage (chosen)", encode_raw_image, raw_frame),
                 ("CompressedImage PNG", png_message, png_frame)]
    for kind, frames in frames_by_kind.items():
        for name, encode_frame, decode_frame in encodings:
            data = image_mcap(frames, encode_frame)
            np.testing.assert_array_equal(read_images(data, decode_frame), frames)
            write = timed(lambda e=encode_frame, f=frames: image_mcap(f, e), runs=3)
            read = timed(lambda d=data, r=decode_frame: read_images(d, r), runs=3)
            rows.append(f"| {kind} | {name} | {write} | {read} | "
                        f"{len(data) / 1e6:.2f} |")
    return rows


def sampling_rows(episode: dict[str, np.ndarray]) -> tuple[list[str], Replay]:
    rows = []
    for oversample_ends in (False, True):
        replay = Replay(40 * STEPS, LENGTH, np.random.default_rng(0), oversample_ends)
        for _ in range(40):
            replay.add_episode(episode)
        replay.sample(BATCH)
        sample = timed(lambda replay=replay: replay.sample(BATCH), runs=50)
        rows.append(f"| {BATCH}x{LENGTH} | {oversample_ends} | {replay.num_steps:,} | {sample} |")
    return rows, replay


def checkpoint_row(directory: Path) -> str:
    """Save and restore time of a params + Adam moments sized pytree (3 x 10M float32)."""
    rng = np.random.default_rng(0)
    params = {f"layer{i}": rng.normal(size=(1000, 1000)).astype(np.float32) for i in range(10)}
    tree = {"params": params, "mu": params, "nu": params}
    step = iter(range(1_000_000))
    save = timed(lambda: checkpoint.save(directory, next(step), tree, {"n": 1}), 3, scale=1)
    restore = timed(lambda: checkpoint.restore(directory, tree), runs=3, scale=1)
    size = checkpoint.latest(directory).stat().st_size
    return (f"Checkpoint of {size / 1e6:.0f} MB (3 x 10M float32): save {save} s, "
            f"restore {restore} s, wall (CPU), median of 3.")


def main() -> str:
    rng = np.random.default_rng(0)
    frames = {
        "shapes": shapes_frames(STEPS, rng),
        "noise": rng.integers(0, 256, (STEPS, 64, 64, 3), dtype=np.uint8),
    }
    episodes = {kind: make_episode(f, rng) for kind, f in frames.items()}
    with tempfile.TemporaryDirectory() as directory:
        files = file_rows(episodes, Path(directory))
    with tempfile.TemporaryDirectory() as directory:
        checkpoints = checkpoint_row(Path(directory))
    encodings = encoding_rows(frames)
    sampling, replay = sampling_rows(episodes["shapes"])
    per_step = replay.bytes_per_step
    gray_step = 64 * 64 + 4 * 18 + 4 + 1 + 1  # Atari: 64x64 gray, 18 one-hot actions
    lines = [
        "## Replay",
        "",
        f"Episodes of {STEPS} steps, 64x64x3 uint8 images, {ACTION_DIM}-d actions; median of "
        f"{RUNS} runs (sampling: 50). Times are wall (CPU of this process); the CPU time "
        "is the better estimate on a shared machine. Write = encode + atomic write with fsync.",
        "",
        "| images | write ms/episode | read ms/episode | MB/episode | bytes/step on disk |",
        "|---|---|---|---|---|",
        *files,
        "",
        "Image encodings compared on the same frames (an MCAP file with the image channel only,"
        " zstd chunks; per-message decoding):",
        "",
        "| images | encoding | encode ms/episode | decode ms/episode | MB/episode |",
        "|---|---|---|---|---|",
        *encodings,
        "",
        "Sampling from memory (vectorised gather from the ring buffer):",
        "",
        "| batch | oversample_ends | steps stored | ms/batch |",
        "|---|---|---|---|",
        *sampling,
        "",
        f"Replay memory: {per_step:,} bytes/frame (64x64x3 + {ACTION_DIM}-d action + reward "
        f"+ flags) = {per_step * 1e6 / 2**30:.1f} GiB per million frames; Atari 64x64 gray "
        f"with 18 actions: {gray_step:,} bytes/frame = {gray_step * 1e6 / 2**30:.1f} GiB per "
        "million frames.",
        "",
        checkpoints,
        "",
    ]
    text = "\n".join(lines)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text)
    return text


if __name__ == "__main__":
    main()
