"""pymunk physics of BringBackShapes.

One ``Simulation`` holds one episode's space. A physics sub-step is split in two calls so that
the environment can draw the scene between them, as the original does (it draws before
``space.step``, spec defect #5):

    newly_scored = sim.control_and_score(angle, force, rng)   # distractors, agent, scoring
    sim.advance()                                             # velocity cap + space.step(1/60)
"""

import math
from typing import NamedTuple

import numpy as np
import pymunk

from bbs import _chipmunk
from bbs.geometry import (
    AGENT_RADIUS,
    DISTRACTOR_RADIUS,
    DISTRACTOR_VERTICES,
    OBJECT_SHAPES,
    ArenaGeometry,
)
from bbs.layout import Layout

DT = 1.0 / 60.0
DAMPING = 0.7  # velocity kept after one second; chipmunk applies DAMPING ** dt per step
DAMPING_PER_STEP = DAMPING**DT

# The original applies its forces 100 times per sub-step in a Python loop; we apply the sum.
FORCE_REPEATS = 100
DISTRACTOR_FORCE_SCALE = 0.2
DISTRACTOR_MAX_FORCE = 400.0
DISTRACTOR_HOLD_RANGE = (2, 10)  # half-open: holds of 2..9 sub-steps
CLAMP_VELOCITY_FACTOR = -0.3

OBJECT_MASS, OBJECT_MOMENT = 20.0, 1e6
ENTITY_DENSITY = 0.1  # agent and distractors: mass and moment come from the shape's density
SOFT_SPEED_CAP, SOFT_CAP_FACTOR = 800.0, 0.99

WALL_ELASTICITY, WALL_FRICTION = 0.7, 1.0
AGENT_ELASTICITY, AGENT_FRICTION = 0.0, 0.5
OBJECT_ELASTICITY, OBJECT_FRICTION = 1.0, 0.5
DISTRACTOR_ELASTICITY, DISTRACTOR_FRICTION = 0.0, 0.5


class Pose(NamedTuple):
    x: float
    y: float
    angle: float


class Scene(NamedTuple):
    """What is drawn: poses of the agent, the not-yet-scored objects and the distractors."""

    agent: Pose
    objects: tuple[Pose, ...]
    object_shapes: tuple[str, ...]
    object_colours: tuple[str, ...]
    object_ids: tuple[int, ...]  # index of each drawn object in the layout
    distractors: tuple[Pose, ...]


def _soft_capped_velocity_update(body: pymunk.Body, gravity, damping: float, dt: float) -> None:
    """The original's ``limit_velocity``: the normal update, then v <- 0.99 v if |v| > 800."""
    pymunk.Body.update_velocity(body, gravity, damping, dt)
    vx, vy = body.velocity
    if math.hypot(vx, vy) > SOFT_SPEED_CAP:
        body.velocity = (SOFT_CAP_FACTOR * vx, SOFT_CAP_FACTOR * vy)


def _pose(body: pymunk.Body) -> Pose:
    x, y = _chipmunk.position(body)
    return Pose(x, y, _chipmunk.angle(body))


class _Distractor:
    """A Brownian kite: holds a random push for 2..9 sub-steps, then draws a new one."""

    def __init__(self, body: pymunk.Body):
        self.body = body
        self.hold = 0
        self.force = (0.0, 0.0)
        # Force applied at the body origin while the centre of gravity is offset: lever arm
        # r = origin - cog (rotated with the body), giving a small torque.
        cog = body.center_of_gravity
        self.local_arm = (-cog.x, -cog.y)

    def resample(self, rng: np.random.Generator) -> None:
        """Force U(0, 400), direction a uniform whole degree, hold uniform in 2..9 sub-steps.

        One ``rng.random(3)`` call (``Generator.integers`` costs several times more).
        """
        u_force, u_degree, u_hold = rng.random(3).tolist()
        magnitude = DISTRACTOR_MAX_FORCE * u_force
        direction = math.radians(math.floor(360 * u_degree))
        low, high = DISTRACTOR_HOLD_RANGE
        self.hold = low + math.floor((high - low) * u_hold)
        scale = FORCE_REPEATS * DISTRACTOR_FORCE_SCALE * magnitude
        self.force = (scale * math.cos(direction), scale * math.sin(direction))


class Simulation:
    """One episode's pymunk space built from a ``Layout``."""

    def __init__(self, geometry: ArenaGeometry, layout: Layout, odd_force_point: bool = True):
        self.geometry = geometry
        self.odd_force_point = odd_force_point
        self.space = pymunk.Space()
        self.space.damping = DAMPING
        self._add_walls()
        self.agent = self._add_agent(layout)
        self.distractors = [self._add_distractor(p.x, p.y, p.angle) for p in layout.distractors]
        self.object_bodies = [self._add_object(o) for o in layout.objects]
        self.object_shapes = tuple(o.shape for o in layout.objects)
        self.object_colours = tuple(o.colour for o in layout.objects)
        self.remaining = list(range(len(layout.objects)))  # indices not yet scored
        self.scored = np.zeros(len(layout.objects), dtype=bool)
        self._capped = set()  # objects whose velocity update currently applies the soft cap
        # The original teleports entities past the goal line on their first sub-step; doing it
        # now makes the reset observation show where the episode really starts.
        self._clamp(self.agent, AGENT_RADIUS)
        for distractor in self.distractors:
            self._clamp(distractor.body, DISTRACTOR_RADIUS)

    # ----------------------------------------------------------------------------- building
    def _add_walls(self) -> None:
        for rect in self.geometry.walls:
            corners = [(rect.x0, rect.y0), (rect.x1, rect.y0), (rect.x1, rect.y1),
                       (rect.x0, rect.y1)]
            wall = pymunk.Poly(self.space.static_body, corners)
            wall.elasticity, wall.friction = WALL_ELASTICITY, WALL_FRICTION
            self.space.add(wall)

    def _add_agent(self, layout: Layout) -> pymunk.Body:
        body = pymunk.Body()
        body.position = (layout.agent.x, layout.agent.y)
        body.angle = layout.agent.angle
        shape = pymunk.Circle(body, AGENT_RADIUS)
        shape.density = ENTITY_DENSITY  # m = 0.1 * pi * 15^2 = 70.686, I = 7952.16 (defect #1)
        shape.elasticity, shape.friction = AGENT_ELASTICITY, AGENT_FRICTION
        self.space.add(body, shape)
        return body

    def _add_distractor(self, x: float, y: float, angle: float) -> _Distractor:
        body = pymunk.Body()
        body.position, body.angle = (x, y), angle
        shape = pymunk.Poly(body, DISTRACTOR_VERTICES)
        shape.density = ENTITY_DENSITY  # m = 60, I = 6583.3, cog = (-6.667, 0)
        shape.elasticity, shape.friction = DISTRACTOR_ELASTICITY, DISTRACTOR_FRICTION
        self.space.add(body, shape)
        return _Distractor(body)

    def _add_object(self, placement) -> pymunk.Body:
        body = pymunk.Body(OBJECT_MASS, OBJECT_MOMENT)
        body.position, body.angle = (placement.x, placement.y), placement.angle
        shape = pymunk.Poly(body, OBJECT_SHAPES[placement.shape])
        shape.elasticity, shape.friction = OBJECT_ELASTICITY, OBJECT_FRICTION
        self.space.add(body, shape)
        return body

    # ----------------------------------------------------------------------------- stepping
    def _clamp(self, body: pymunk.Body, radius: float) -> bool:
        """Goal-line clamp: if x + r > goal_x, teleport to goal_x - r and set v <- -0.3 v."""
        x, y = _chipmunk.position(body)
        if x + radius <= self.geometry.goal_x:
            return False
        body.position = (self.geometry.goal_x - radius, y)
        vx, vy = body.velocity
        body.velocity = (CLAMP_VELOCITY_FACTOR * vx, CLAMP_VELOCITY_FACTOR * vy)
        return True

    def _push_distractors(self, rng: np.random.Generator) -> None:
        for distractor in self.distractors:
            if distractor.hold == 0:
                distractor.resample(rng)
            distractor.hold -= 1
            body = distractor.body
            fx, fy = distractor.force
            body_angle = _chipmunk.angle(body)
            c, s = math.cos(body_angle), math.sin(body_angle)
            ax, ay = distractor.local_arm
            arm_x, arm_y = c * ax - s * ay, s * ax + c * ay
            _chipmunk.set_force_and_torque(body, fx, fy, arm_x * fy - arm_y * fx)
            self._clamp(body, DISTRACTOR_RADIUS)

    def _push_agent(self, angle: float, force: float) -> None:
        """Closed form of the original's 100 applications of F at the point (x, x).

        Each application adds torque (y - x) * Fx (lever arm (0, x - y)). The goal-line clamp
        runs after the first application, so if it fires the sum is
        Fx * ((y - x_before) + 99 * (y - x_after)); otherwise 100 * (y - x) * Fx.
        """
        fx, fy = force * math.cos(angle), force * math.sin(angle)
        body = self.agent
        x_before, y = _chipmunk.position(body)
        clamped = self._clamp(body, AGENT_RADIUS)
        if self.odd_force_point:
            x_after = self.geometry.goal_x - AGENT_RADIUS if clamped else x_before
            torque = fx * ((y - x_before) + (FORCE_REPEATS - 1) * (y - x_after))
        else:
            torque = 0.0
        _chipmunk.set_force_and_torque(body, FORCE_REPEATS * fx, FORCE_REPEATS * fy, torque)

    def _remove_scored(self) -> int:
        score_x = self.geometry.score_x
        bodies = self.object_bodies
        crossed = [i for i in self.remaining if _chipmunk.position(bodies[i])[0] >= score_x]
        for i in crossed:
            body = self.object_bodies[i]
            self.space.remove(body, *body.shapes)
            self.remaining.remove(i)
            self._capped.discard(i)
            self.scored[i] = True
        return len(crossed)

    @property
    def num_scored(self) -> int:
        return len(self.object_bodies) - len(self.remaining)

    def control_and_score(self, angle: float, force: float, rng: np.random.Generator) -> int:
        """Apply this sub-step's forces and remove scored objects; returns how many scored."""
        self._push_distractors(rng)
        self._push_agent(angle, force)
        return self._remove_scored()

    def _update_soft_caps(self) -> None:
        """Give the capped velocity update only to objects that will exceed the cap this step.

        An object's velocity update is v <- v * DAMPING_PER_STEP (no force acts on objects),
        so the original's test |v_new| > 800 can be made before the step. Python velocity
        callbacks cost ~3.5 us per body and step, so they are installed only when needed.
        """
        for i in self.remaining:
            body = self.object_bodies[i]
            vx, vy = _chipmunk.velocity(body)
            needs_cap = math.hypot(vx * DAMPING_PER_STEP, vy * DAMPING_PER_STEP) > SOFT_SPEED_CAP
            if needs_cap != (i in self._capped):
                if needs_cap:
                    body.velocity_func = _soft_capped_velocity_update
                    self._capped.add(i)
                else:
                    body.velocity_func = pymunk.Body.update_velocity
                    self._capped.discard(i)

    def advance(self) -> None:
        self._update_soft_caps()
        _chipmunk.step(self.space, DT)

    # ----------------------------------------------------------------------------- reading
    def scene(self) -> Scene:
        remaining = tuple(self.remaining)
        return Scene(
            agent=_pose(self.agent),
            objects=tuple(_pose(self.object_bodies[i]) for i in remaining),
            object_shapes=tuple(self.object_shapes[i] for i in remaining),
            object_colours=tuple(self.object_colours[i] for i in remaining),
            object_ids=remaining,
            distractors=tuple(_pose(d.body) for d in self.distractors),
        )

    def state(self) -> dict:
        """True state (after the last physics step), as plain numpy arrays and tuples."""

        def poses(bodies):
            rows = [(*b.position, b.angle) for b in bodies]
            return np.array(rows, dtype=np.float64).reshape(-1, 3)

        def velocities(bodies):
            rows = [(*b.velocity, b.angular_velocity) for b in bodies]
            return np.array(rows, dtype=np.float64).reshape(-1, 3)

        distractor_bodies = [d.body for d in self.distractors]
        return {
            "agent_pose": poses([self.agent])[0],
            "agent_velocity": velocities([self.agent])[0],
            "object_poses": poses(self.object_bodies),
            "object_velocities": velocities(self.object_bodies),
            "object_shapes": self.object_shapes,
            "object_colours": self.object_colours,
            "object_scored": self.scored.copy(),
            "distractor_poses": poses(distractor_bodies),
            "distractor_velocities": velocities(distractor_bodies),
            "goal_y": self.geometry.goal_y,
        }

