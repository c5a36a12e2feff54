"""DeepMind Control Suite tasks as pixel gymnasium envs (``dmc_<domain>_<task>``).

Observation: the scene rendered to ``size x size`` RGB uint8 after the last physics step of each
agent step (camera 2 for quadruped, 0 otherwise, as DreamerV2). Action: ``Box(-1, 1, (A,))``,
mapped affinely onto the task's action bounds. Every agent step repeats the action
``action_repeat`` times and sums the rewards. The episode is truncated after ``time_limit`` env
steps (physics control steps, before action repeat); it terminates only where dm_control reports
a zero discount, which no suite task does.

Rendering runs on the CPU through OSMesa when no display is available (``MUJOCO_GL=osmesa``,
set here by default before dm_control is imported; ``make`` sets it too). There, drawing the
2048x2048 shadow map dominates the cost of a 64x64 frame; a 512 map halves the render time and
changes the image by 0.02 grey levels on average (measured on walker), so it is the default.

With ``env.background`` set, every observation (reset and step) has a distracting background
(:mod:`vsgjax.envs.backgrounds`) composited behind the agent; it restarts every episode from the
env's RNG and advances one frame per observation. Evaluation envs play the test split of
``env.background_dir``'s videos, training envs the train split.
"""

from __future__ import annotations

import os

os.environ.setdefault("MUJOCO_GL", "osmesa")
os.environ.setdefault("PYOPENGL_PLATFORM", os.environ["MUJOCO_GL"])

import gymnasium  # noqa: E402
import numpy as np  # noqa: E402

from vsgjax.envs.backgrounds import composite, make_background  # noqa: E402
from vsgjax.envs.spec import TaskError  # noqa: E402
from vsgjax.registry.names import did_you_mean  # noqa: E402

CAMERA_BY_DOMAIN = {"quadruped": 2}
SHADOW_MAP_SIZE = 512  # MuJoCo's default (2048 in the suite's models) costs 2x on a CPU renderer


def all_tasks() -> list[tuple[str, str]]:
    """Every (domain, task) pair of the suite."""
    from dm_control import suite

    return [tuple(pair) for pair in suite.ALL_TASKS]


class DMCEnv(gymnasium.Env):
    """One dm_control suite task with pixel observations, action repeat and a time limit."""

    metadata = {"render_modes": ["rgb_array"]}
    render_mode = "rgb_array"

    def __init__(self, domain: str, task: str, *, action_repeat: int, time_limit: int,
                 size: int, seed: int, background=None):
        """``background``: a source of :mod:`vsgjax.envs.backgrounds` (None: the plain
        scene)."""
        from dm_control import suite

        self._env = suite.load(domain, task, task_kwargs={"random": seed})
        self._env.physics.model.vis.quality.shadowsize = SHADOW_MAP_SIZE
        self._repeat = action_repeat
        self._time_limit = time_limit
        self._size = size
        self._camera = CAMERA_BY_DOMAIN.get(domain, 0)
        spec = self._env.action_spec()
        self._low, self._high = spec.minimum.astype(np.float64), spec.maximum.astype(np.float64)
        self.action_space = gymnasium.spaces.Box(-1.0, 1.0, spec.shape, np.float32)
        self.observation_space = gymnasium.spaces.Box(0, 255, (size, size, 3), np.uint8)
        self._env_steps = 0
        self._background = background
        self._backdrop = None  # the background frame of the current observation

    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        if seed is not None:
            self._env.task.random.seed(seed)
            self.action_space.seed(seed)
        self._env.reset()
        self._env_steps = 0
        if self._background is not None:
            self._backdrop = self._background.reset(self.np_random)
        return self._render(), {}

    def step(self, action):
        action = np.clip(np.asarray(action, np.float64), -1.0, 1.0)
        control = self._low + (action + 1.0) / 2.0 * (self._high - self._low)
        reward, terminated, truncated = 0.0, False, False
        for _ in range(self._repeat):
            time_step = self._env.step(control)
            self._env_steps += 1
            reward += time_step.reward or 0.0
            terminated = time_step.last() and time_step.discount == 0.0
            truncated = not terminated and (time_step.last() or self._env_steps >= self._time_limit)
            if terminated or truncated:
                break
        if self._background is not None:
            self._backdrop = self._background.step()
        return self._render(), float(reward), terminated, truncated, {"env_steps": self._env_steps}

    def render(self):
        return self._render()

    def _render(self) -> np.ndarray:
        frame = self._env.physics.render(self._size, self._size, camera_id=self._camera)
        return frame if self._backdrop is None else composite(frame, self._backdrop)

    def close(self):
        """Free the GL context now (at interpreter exit dm_control's own cleanup can fail)."""
        self._env.physics.free()


def parse(task: str, rest: str) -> tuple[str, str]:
    """``dmc_<domain>_<task>`` -> ``(domain, task)``; TaskError listing the tasks otherwise."""
    pairs = all_tasks()
    for domain, name in pairs:
        if f"{domain}_{name}" == rest:
            return domain, name
    family = task.partition("_")[0]
    hint = did_you_mean(rest, [f"{d}_{t}" for d, t in pairs], prefix=f"{family}_")
    raise TaskError(f"unknown DMC task {task!r}{hint}; valid: "
                    + ", ".join(f"{family}_{d}_{t}" for d, t in pairs))


def build(args: tuple[str, str], cfg, seed: int, eval: bool) -> gymnasium.Env:
    """The env of ``cfg``; an evaluation env (``eval``) plays the test split of the videos."""
    background = make_background(cfg.background, cfg.image_size, cfg.background_dir, test=eval)
    return DMCEnv(*args, action_repeat=cfg.action_repeat, time_limit=cfg.time_limit,
                  size=cfg.image_size, seed=seed, background=background)
