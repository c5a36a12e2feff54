"""Generate the README pictures into ``bbs/assets/``: ``python -m bbs.make_figures``.

* ``arena.png``: the full arena with the agent's view box (``render_mode="rgb_array"``);
* ``observations.png``: the 64x64 observation at the same instant, then three more variants,
  each upscaled 4x with nearest-neighbour so pixels stay visible.
"""

from pathlib import Path

import cv2
import numpy as np

import bbs

ASSETS = Path(__file__).parent / "assets"
UPSCALE = 4
FIGURE_VARIANTS = (("bbs_basic_d2", 7), ("bbs_basic", 3), ("bbs_medium", 5), ("bbs_basic_d4", 11))
STEPS = 40


def _run(name: str, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """Observation and full-arena frame after ``STEPS`` random agent steps."""
    env = bbs.make(name, render_mode="rgb_array")
    observation, _ = env.reset(seed=seed)
    actions = np.random.default_rng(seed).uniform(-1, 1, (STEPS, 2))
    for action in actions:
        observation, *_ = env.step(action)
    return observation, env.render()


def _save_rgb(path: Path, image: np.ndarray) -> None:
    cv2.imwrite(str(path), np.ascontiguousarray(image[..., ::-1]))


def main() -> None:
    ASSETS.mkdir(exist_ok=True)
    observations = []
    for index, (name, seed) in enumerate(FIGURE_VARIANTS):
        observation, arena = _run(name, seed)
        if index == 0:
            _save_rgb(ASSETS / "arena.png", arena)
        big = cv2.resize(observation, None, fx=UPSCALE, fy=UPSCALE,
                         interpolation=cv2.INTER_NEAREST)
        observations.append(np.pad(big, ((4, 4), (4, 4), (0, 0)), constant_values=255))
    _save_rgb(ASSETS / "observations.png", np.concatenate(observations, axis=1))
    print(f"wrote {ASSETS / 'arena.png'} and {ASSETS / 'observations.png'}")


if __name__ == "__main__":
    main()
