"""Atari games through ale-py with the DreamerV2 settings (``atari_<game>``).

* sticky actions with probability ``EnvConfig.sticky`` (0.25), the minimal action set
  (``full_action_space=False``) as ``Discrete(n)``;
* on reset, 1..30 no-op frames (uniform, from the env's seeded RNG);
* every agent step repeats the action ``action_repeat`` (4) frames, sums the rewards and
  max-pools the last two frames;
* observation: grayscale (or RGB) resized to ``size x size`` with area interpolation, uint8
  ``(size, size, 1)`` (or ``(size, size, 3)``);
* losing a life does not end the episode (``life_done=False``); the game ends it (terminated);
* truncated after ``time_limit`` frames, counted in agent steps: 108k frames = 27k agent steps.

The preprocessing is gymnasium's ``AtariPreprocessing`` (Machado et al. 2018), which DreamerV2's
wrapper also used.
"""

from __future__ import annotations

import gymnasium
from gymnasium.wrappers import AtariPreprocessing, TimeLimit

from vsgjax.envs.spec import one_of

NOOP_MAX = 30


def all_games() -> list[str]:
    """The ROM ids ale-py ships (``atari_<game>`` uses these, e.g. ``space_invaders``)."""
    import ale_py.roms

    return sorted(ale_py.roms.get_all_rom_ids())


def make_atari(game: str, *, action_repeat: int, time_limit: int, size: int, grayscale: bool,
               sticky: float) -> gymnasium.Env:
    from ale_py import AtariEnv

    base = AtariEnv(game=game, obs_type="grayscale" if grayscale else "rgb", frameskip=1,
                    repeat_action_probability=sticky, full_action_space=False)
    env = AtariPreprocessing(base, noop_max=NOOP_MAX, frame_skip=action_repeat,
                             screen_size=size, terminal_on_life_loss=False,
                             grayscale_obs=grayscale, grayscale_newaxis=True)
    return TimeLimit(env, max_episode_steps=-(-time_limit // action_repeat))


def parse(task: str, game: str) -> tuple[str]:
    """``atari_<game>`` -> ``(game,)``; TaskError listing the games otherwise."""
    return (one_of(task, game, all_games(), "Atari game"),)


def build(args: tuple[str], cfg, seed: int, eval: bool) -> gymnasium.Env:
    return make_atari(args[0], action_repeat=cfg.action_repeat, time_limit=cfg.time_limit,
                      size=cfg.image_size, grayscale=cfg.grayscale, sticky=cfg.sticky)
