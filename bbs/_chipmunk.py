"""Direct calls into pymunk's bundled Chipmunk library for the per-sub-step hot path.

pymunk's public properties wrap every access in Python (a ``Vec2d`` per read, a ``__setattr__``
hook per write, callback and deferred-removal bookkeeping around ``Space.step``). On
BringBackShapes' hot path (~15 reads and writes per physics sub-step) this costs 3-4 times the C
calls themselves, so the simulation reaches the same C functions through ``pymunk._chipmunk``
(pymunk is pinned to >= 7, < 8; ``tests/bbs/test_bbs.py`` checks these against the public API).

``step`` skips what ``pymunk.Space.step`` adds around ``cpSpaceStep``: mass checks of newly
added bodies, post-step callbacks and deferred adds/removals, none of which the simulation uses
(it adds bodies only when building a space and removes them only between steps).
"""

import pymunk
from pymunk._chipmunk import lib


def position(body: pymunk.Body) -> tuple[float, float]:
    p = lib.cpBodyGetPosition(body._body)
    return p.x, p.y


def velocity(body: pymunk.Body) -> tuple[float, float]:
    v = lib.cpBodyGetVelocity(body._body)
    return v.x, v.y


def angle(body: pymunk.Body) -> float:
    return lib.cpBodyGetAngle(body._body)


def set_force_and_torque(body: pymunk.Body, fx: float, fy: float, torque: float) -> None:
    lib.cpBodySetForce(body._body, (fx, fy))
    lib.cpBodySetTorque(body._body, torque)


def step(space: pymunk.Space, dt: float) -> None:
    lib.cpSpaceStep(space._space, dt)
