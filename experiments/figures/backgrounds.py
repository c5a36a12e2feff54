"""One observation of a ``dmc_`` pixel task with each distracting background (``env.background``).

    python -m experiments.figures.backgrounds [--out PATH] [--seed S] [--steps N]

Builds ``dmc_cartpole_swingup`` at the agent's view (64x64, the dmc preset otherwise) with
seed ``--seed`` once per background (``none``, ``video``, ``dots``, ``noise``, ``color``), takes
``--steps`` uniform random actions (the same for every background, drawn from the seed) so that
the dots and the video have moved, and draws the last observation of each, upscaled to 128x128
(nearest neighbour), as one labelled row. The physics, the actions and so the cartpole are the
same in every panel; only the bluish pixels (the skybox and the floor) differ.

No videos ship with the repository, so ``video`` plays a folder of two short synthetic GIFs
written by :func:`write_videos` into a temporary directory (a drifting colour gradient and
moving stripes): stand-ins for the Kinetics-400 "driving car" clips of the paper. A training
env plays the train split (the first file by name), so the panel shows the gradient.

Deterministic by seed. Writes ``docs/figures/backgrounds.png`` by default.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
FIGURE = ROOT / "docs" / "figures" / "backgrounds.png"
TASK, IMAGE_SIZE, SHOWN_SIZE = "dmc_cartpole_swingup", 64, 128
BACKGROUNDS = ("none", "video", "dots", "noise", "color")
STEPS = 5
VIDEO_FRAMES, VIDEO_SIZE = 24, 96


def write_videos(folder: Path, frames: int = VIDEO_FRAMES, size: int = VIDEO_SIZE) -> list[Path]:
    """Two synthetic GIFs in ``folder``: ``a_gradient.gif``, a diagonal colour gradient whose
    hues drift each frame, and ``b_stripes.gif``, diagonal magenta / green stripes moving
    across. Both are smooth, saturated patterns, clearly not the agent."""
    import imageio.v3 as iio

    y, x = np.mgrid[0:size, 0:size] / size
    gradient, stripes = [], []
    for t in range(frames):
        phase = 2 * np.pi * t / frames
        channels = [np.sin(2 * np.pi * (x + y) / 2 + phase + shift) for shift in (0, 2.1, 4.2)]
        gradient.append(np.stack(channels, -1) * 0.5 + 0.5)
        band = np.sin(2 * np.pi * (4 * (x - y) + t / frames)) > 0
        stripes.append(np.where(band[..., None], [0.9, 0.1, 0.8], [0.1, 0.8, 0.3]))
    paths = []
    for name, video in (("a_gradient.gif", gradient), ("b_stripes.gif", stripes)):
        path = folder / name
        iio.imwrite(path, (np.stack(video) * 255).round().astype(np.uint8), loop=0)
        paths.append(path)
    return paths


def observations(seed: int = 0, steps: int = STEPS, video_dir: str = "") -> dict[str, np.ndarray]:
    """``{background: uint8 [64, 64, 3]}``: the observation after ``steps`` random actions from
    the seeded reset, per background (``video`` plays ``video_dir``)."""
    from vsgjax.config import make_config
    from vsgjax.envs import make_env

    frames = {}
    for background in BACKGROUNDS:
        overrides = [f"env.image_size={IMAGE_SIZE}", f"env.background={background}"]
        if background == "video":
            overrides.append(f"env.background_dir={video_dir}")
        env = make_env(make_config(TASK, overrides=overrides).env, seed=seed)
        try:
            obs, _ = env.reset()
            actions = np.random.default_rng(seed).uniform(-1, 1, (steps, *env.action_space.shape))
            for action in actions.astype(np.float32):
                obs = env.step(action)[0]
        finally:
            env.close()
        frames[background] = np.asarray(obs)
    return frames


def upscale(frame: np.ndarray, size: int = SHOWN_SIZE) -> np.ndarray:
    """Nearest-neighbour upscaling of a square frame to ``size`` x ``size``."""
    factor = size // frame.shape[0]
    return np.repeat(np.repeat(frame, factor, 0), factor, 1)


def draw(frames: dict[str, np.ndarray], path: Path, seed: int, steps: int) -> None:
    """One labelled row of the upscaled frames, saved as a small PNG at ``path``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(frames), figsize=(1.45 * len(frames), 1.95))
    for ax, (background, frame) in zip(axes, frames.items(), strict=True):
        ax.imshow(upscale(frame), interpolation="nearest")
        ax.set_title(f"env.background={background}", fontsize=6.5, family="monospace")
        ax.set_xticks([])
        ax.set_yticks([])
    fig.suptitle(f"{TASK}, {IMAGE_SIZE}x{IMAGE_SIZE}, seed {seed}, after {steps} random "
                 "actions\n(video: synthetic stand-ins for the Kinetics clips)", fontsize=7)
    fig.tight_layout(pad=0.3, w_pad=0.4)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=100, metadata={"Software": None})
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.figures.backgrounds",
                                     description=__doc__.split("\n")[0])
    parser.add_argument("--out", type=Path, default=FIGURE, help=f"default: {FIGURE}")
    parser.add_argument("--seed", type=int, default=0, help="env and action seed")
    parser.add_argument("--steps", type=int, default=STEPS, help="random actions after reset")
    args = parser.parse_args(argv)
    os.environ.setdefault("MUJOCO_GL", "osmesa")  # headless rendering, before dm_control loads
    with tempfile.TemporaryDirectory() as folder:
        write_videos(Path(folder))
        frames = observations(args.seed, args.steps, folder)
    draw(frames, args.out, args.seed, args.steps)
    print(f"wrote {args.out} ({args.out.stat().st_size / 1024:.1f} KB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
