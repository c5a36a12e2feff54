"""``BringBackShapesEnv``: the gymnasium environment (docs/bbs.md).

One agent step repeats the action for ``action_repeat`` physics sub-steps (dt = 1/60) and
returns the summed reward (objects scored). The observation is the agent's view, drawn once per
agent step from the state *before* the last sub-step's ``space.step``, as in the original
(spec defect #5, kept): it lags the true state by one physics step.
"""

import math
from numbers import Integral, Real

import gymnasium as gym
import numpy as np

from bbs import window
from bbs.discovery import DiscoveryTracker
from bbs.geometry import ArenaGeometry, arena_geometry
from bbs.layout import Layout, parse_layout, sample_layout, smallest_arena_size
from bbs.physics import DT, Scene, Simulation
from bbs.render import ViewRenderer, draw_arena, view_box

MAX_FORCE = 400.0
TWO_PI = 2 * math.pi
RENDER_MODES = ("human", "rgb_array")


def available_render_modes() -> list[str]:
    """The render modes that work here: ``"human"`` needs pygame (the ``play`` extra)."""
    return [m for m in RENDER_MODES if m != "human" or window.pygame_available()]


def smallest_arena_scale() -> float:
    """The smallest ``arena_scale`` whose arena fits the spawn rule (``smallest_arena_size``).

    Found on the geometry itself (``int(800 S) x int(700 S)``, float truncation included).
    """
    width, length = smallest_arena_size()
    scale = max(width / 800, length / 700)
    while not _fits(arena_geometry(scale), width, length):
        scale = math.nextafter(scale, math.inf)
    return scale


def _fits(geometry: ArenaGeometry, width: int, length: int) -> bool:
    return geometry.width >= width and geometry.length >= length


MIN_ARENA_SCALE = smallest_arena_scale()


def _check_int(name: str, value, minimum: int) -> None:
    if not isinstance(value, Integral) or isinstance(value, bool) or value < minimum:
        raise ValueError(f"{name} must be an integer >= {minimum}; got {value!r}")


def _validate_options(arena_scale, num_objects, num_distractors, agent_view_size, action_repeat,
                      time_limit, obs_size, canvas_size, render_mode) -> None:
    if not isinstance(arena_scale, Real) or not math.isfinite(arena_scale) or arena_scale <= 0:
        raise ValueError(f"arena_scale must be a finite number > 0; got {arena_scale!r}")
    geometry = arena_geometry(arena_scale)
    if not _fits(geometry, *smallest_arena_size()):
        raise ValueError(
            f"arena_scale={arena_scale!r} is too small: the smallest valid scale is "
            f"{MIN_ARENA_SCALE!r} (its {geometry.width}x{geometry.length} arena leaves no room "
            f"to spawn the agent clear of the walls, left of the goal line)"
        )
    _check_int("num_objects", num_objects, 1)
    _check_int("num_distractors", num_distractors, 0)
    _check_int("agent_view_size", agent_view_size, 1)
    _check_int("action_repeat", action_repeat, 1)
    if time_limit is not None:
        _check_int("time_limit", time_limit, 0)
    _check_int("obs_size", obs_size, 1)
    if canvas_size is not None:
        _check_int("canvas_size", canvas_size, obs_size)
    view = 2 * agent_view_size
    if view > min(geometry.width, geometry.length):
        raise ValueError(
            f"agent_view_size={agent_view_size} gives a {view}x{view} view box, larger than the "
            f"{geometry.width}x{geometry.length} arena at arena_scale={arena_scale}"
        )
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise ValueError(f"render_mode={render_mode!r} is not None or one of {list(RENDER_MODES)}")
    if render_mode == "human" and not window.pygame_available():
        raise ImportError(window.PYGAME_MISSING)


class BringBackShapesEnv(gym.Env):
    """Push the coloured shapes through the opening on the right; reward 1 per shape scored.

    Args:
        render_mode: None, ``"rgb_array"`` (``render()`` returns the full arena with the view
            box, like the paper's figure) or ``"human"`` (a pygame window, extra ``play``;
            without pygame it raises ImportError, and ``metadata["render_modes"]`` omits it).
        arena_scale: S; the arena is ``int(800 S) x int(700 S)`` px (walls, goal width, shapes
            and the view box do not scale). At least ``MIN_ARENA_SCALE`` (0.475): below it the
            agent can't spawn clear of the walls left of the goal line.
        num_objects: shapes per episode (the maximum if ``variable_num_objects``).
        num_distractors: Brownian kites (the maximum if ``variable_num_distractors``).
        variable_num_objects: draw the count uniformly from 1..num_objects at each reset.
        variable_num_distractors: draw the count uniformly from 0..num_distractors at each reset.
        variable_goal_position: draw the opening's top edge uniformly at each reset so that the
            opening stays between the top and bottom walls; the wall blocks move with it.
        agent_view_size: half the side of the square view box, in arena px (original 125).
        action_repeat: physics sub-steps per agent step.
        time_limit: the episode is truncated after the first sub-step whose index (from 0)
            exceeds ``time_limit``, i.e. after ``time_limit + 2`` sub-steps: 751 agent steps for
            the default 3000 and repeat 4 (the original's rule, spec 3.5). ``None``: no limit.
        obs_size: the observation is ``obs_size x obs_size x 3`` uint8.
        canvas_size: resolution the view is drawn at before an area resize to ``obs_size``;
            ``None`` draws directly at ``obs_size``.
        normalize_actions: actions in [-1, 1]^2 mapped to angle (a0 + 1) pi and force
            (a1 + 1) 200; otherwise raw (angle in [0, 2 pi], force in [0, 400]). Out-of-range
            values are clipped to the action space; NaN/inf or a wrong shape raises ValueError.
        odd_force_point: apply the push at the point (x, x) like the original (a large spin,
            spec defect #2); False pushes through the centre (no torque).
        include_state_in_info: add ``true_state()`` to every ``info`` (costs ~20 us per step).
    """

    metadata = {"render_modes": available_render_modes(), "render_fps": 15}

    def __init__(
        self,
        render_mode: str | None = None,
        arena_scale: float = 1.0,
        num_objects: int = 5,
        num_distractors: int = 0,
        variable_num_objects: bool = False,
        variable_num_distractors: bool = False,
        variable_goal_position: bool = False,
        agent_view_size: int = 125,
        action_repeat: int = 4,
        time_limit: int | None = 3000,
        obs_size: int = 64,
        canvas_size: int | None = None,
        normalize_actions: bool = True,
        odd_force_point: bool = True,
        include_state_in_info: bool = False,
    ):
        _validate_options(arena_scale, num_objects, num_distractors, agent_view_size,
                          action_repeat, time_limit, obs_size, canvas_size, render_mode)
        self.render_mode = render_mode
        self.arena_scale = float(arena_scale)
        self.num_objects, self.num_distractors = num_objects, num_distractors
        self.variable_num_objects = variable_num_objects
        self.variable_num_distractors = variable_num_distractors
        self.variable_goal_position = variable_goal_position
        self.agent_view_size, self.action_repeat, self.time_limit = (
            agent_view_size, action_repeat, time_limit)
        self.normalize_actions, self.odd_force_point = normalize_actions, odd_force_point
        self.include_state_in_info = include_state_in_info
        self.metadata = {"render_modes": available_render_modes(),
                         "render_fps": round(1 / (DT * action_repeat))}
        self._default_geometry = arena_geometry(self.arena_scale)
        self._renderer = ViewRenderer(obs_size, canvas_size or obs_size, 2 * agent_view_size)
        self.observation_space = gym.spaces.Box(0, 255, (obs_size, obs_size, 3), np.uint8)
        if normalize_actions:
            self.action_space = gym.spaces.Box(-1.0, 1.0, (2,), np.float32)
        else:
            self.action_space = gym.spaces.Box(
                np.array([0.0, 0.0], np.float32), np.array([TWO_PI, MAX_FORCE], np.float32))
        self._sim: Simulation | None = None
        self._last_scene: Scene | None = None
        self.layout: Layout | None = None  # this episode's starting layout (set by reset)
        self._window = None

    # ----------------------------------------------------------------------------- episode
    def reset(self, *, seed: int | None = None, options: dict | None = None):
        super().reset(seed=seed)
        options = dict(options or {})
        layout_spec = options.pop("layout", None)
        if options:
            raise ValueError(f"unknown reset options {sorted(options)}; only 'layout' is accepted")
        if layout_spec is None:
            layout = self._sample_layout()
        else:
            layout = parse_layout(layout_spec, self._default_geometry)
            if not layout.objects:
                raise ValueError("layout must contain at least one object")
        self.layout = layout
        geometry = arena_geometry(self.arena_scale, layout.goal_y)
        self._sim = Simulation(geometry, layout, self.odd_force_point)
        self._sub_steps = 0
        self._agent_steps = 0
        self._episode_over = False
        self._tracker = DiscoveryTracker(len(layout.objects))
        observation = self._observe()
        if self.render_mode == "human":
            self.render()
        return observation, self._info()

    def _sample_layout(self) -> Layout:
        rng = self.np_random
        goal_y = None
        if self.variable_goal_position:
            goal_y = float(rng.uniform(*self._default_geometry.goal_y_range))
        num_objects = self.num_objects
        if self.variable_num_objects:
            num_objects = int(rng.integers(1, self.num_objects + 1))
        num_distractors = self.num_distractors
        if self.variable_num_distractors:
            num_distractors = int(rng.integers(0, self.num_distractors + 1))
        geometry = arena_geometry(self.arena_scale, goal_y)
        return sample_layout(rng, geometry, num_objects, num_distractors, goal_y)

    def step(self, action):
        if self._sim is None:
            raise RuntimeError("call reset() before step()")
        if self._episode_over:
            raise RuntimeError("the episode is over (terminated or truncated); call reset()")
        angle, force = self._decode(action)
        sim, rng = self._sim, self.np_random
        reward, all_scored, time_up = 0.0, False, False
        for repeat in range(self.action_repeat):
            reward += sim.control_and_score(angle, force, rng)
            all_scored = not sim.remaining
            time_up = self.time_limit is not None and self._sub_steps > self.time_limit
            self._sub_steps += 1
            last = all_scored or time_up or repeat == self.action_repeat - 1
            if last:
                self._agent_steps += 1
                observation = self._observe()
            sim.advance()
            if last:
                break
        self._episode_over = all_scored or time_up
        info = self._info()
        if self._episode_over:
            info["discovery"] = self._tracker.summary(self._agent_steps, sim.scored)
        if self.render_mode == "human":
            self.render()
        return observation, reward, all_scored, time_up and not all_scored, info

    def _decode(self, action) -> tuple[float, float]:
        """Map an action to (angle, force), clipping out-of-range values to the action space."""
        try:  # None converts to NaN; other non-numbers raise here
            values = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            values = None
        if values is not None and values.shape != (2,):
            raise ValueError(f"action must have shape (2,); got shape {values.shape}")
        a0, a1 = (math.nan, math.nan) if values is None else values.tolist()
        if not (math.isfinite(a0) and math.isfinite(a1)):
            raise ValueError(f"action must be two finite numbers; got {action!r}")
        if self.normalize_actions:
            a0, a1 = min(max(a0, -1.0), 1.0), min(max(a1, -1.0), 1.0)
            return (a0 + 1.0) * math.pi, (a1 + 1.0) * MAX_FORCE / 2
        return min(max(a0, 0.0), TWO_PI), min(max(a1, 0.0), MAX_FORCE)

    def _observe(self) -> np.ndarray:
        """Draw the agent's view and record which objects it shows completely."""
        scene = self._sim.scene()
        box = view_box(scene.agent, self.agent_view_size, self._sim.geometry)
        observation, fully_visible = self._renderer.draw(scene, self._sim.geometry, box)
        self._tracker.observe(self._agent_steps, fully_visible)
        self._last_scene = scene
        return observation

    def _info(self) -> dict:
        info = {"scored": self._sim.num_scored, "sub_steps": self._sub_steps}
        if self.include_state_in_info:
            info["state"] = self.true_state()
        return info

    # ----------------------------------------------------------------------------- inspection
    @property
    def geometry(self) -> ArenaGeometry:
        """This episode's arena geometry (the default one before the first reset)."""
        return self._default_geometry if self._sim is None else self._sim.geometry

    @property
    def scene(self) -> Scene:
        """The poses drawn in the last observation."""
        return self._last_scene

    def true_state(self) -> dict:
        """Current physical state (after the last physics step).

        Keys: ``agent_pose`` (x, y, angle), ``agent_velocity`` (vx, vy, omega),
        ``object_poses`` [N, 3] and ``object_velocities`` [N, 3] (a scored object keeps the
        values it had when it was removed), ``object_shapes``, ``object_colours``,
        ``object_scored`` [N] bool, ``distractor_poses`` [D, 3], ``distractor_velocities``
        [D, 3], ``goal_y``, ``sub_steps`` and ``agent_steps``. Units: px, rad, px/s, rad/s.
        """
        if self._sim is None:
            raise RuntimeError("call reset() before true_state()")
        return self._sim.state() | {"sub_steps": self._sub_steps, "agent_steps": self._agent_steps}

    # ----------------------------------------------------------------------------- rendering
    def render(self):
        if self.render_mode is None or self._sim is None:
            return None
        box = view_box(self._last_scene.agent, self.agent_view_size, self._sim.geometry)
        image = draw_arena(self._last_scene, self._sim.geometry, box)
        if self.render_mode == "rgb_array":
            return image
        if self._window is None:
            from bbs.window import Window

            self._window = Window("BringBackShapes", image.shape[1], image.shape[0])
        self._window.show(image, self.metadata["render_fps"])
        return None

    def close(self):
        if self._window is not None:
            self._window.close()
            self._window = None
