"""Named access to MJX data, like dm_control's ``physics.named`` (ids resolved when traced)."""

from __future__ import annotations

import jax
from mujoco import mjx

from vsgjax.envs.mjx.core import Physics

# Row-major entries of a 3x3 rotation matrix, as dm_control names them ("zz" is R[2, 2]).
XMAT = {"xx": (0, 0), "xy": (0, 1), "xz": (0, 2), "yx": (1, 0), "yy": (1, 1), "yz": (1, 2),
        "zx": (2, 0), "zy": (2, 1), "zz": (2, 2)}


def body(phys: Physics, name: str) -> int:
    return phys.mj.body(name).id


def geom(phys: Physics, name: str) -> int:
    return phys.mj.geom(name).id


def sensor(phys: Physics, data: mjx.Data, name: str) -> jax.Array:
    """The sensor's slice of ``sensordata`` (always a vector)."""
    s = phys.mj.sensor(name)
    adr, dim = int(s.adr[0]), int(s.dim[0])
    return data.sensordata[adr:adr + dim]


def xmat(data: mjx.Data, bodies, entries: tuple[str, ...]) -> jax.Array:
    """``named.data.xmat[bodies, entries]``: shape ``bodies.shape + (len(entries),)``."""
    rows = [XMAT[e][0] for e in entries]
    cols = [XMAT[e][1] for e in entries]
    return data.xmat[bodies][..., rows, cols]
