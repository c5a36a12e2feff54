"""Whether a run fits in this machine's memory, checked before it writes anything.

The estimate is a lower bound of what the run holds for its whole length, per seed:

- the agent's state (parameters, optimizer moments, slow critic...), from
  ``jax.eval_shape`` of its ``init``: exact, nothing is allocated;
- the replay: the device loop allocates its whole ring of ``train.replay_capacity`` steps when
  it starts (exact, from the same ``eval_shape``); the host loop's grows as episodes arrive, so
  it counts the steps the run can store, ``min(train.replay_capacity, stored steps by
  train.steps)``, at the bytes per step of the env's spec.

Activations, compiled programs and checkpoint copies come on top, so a run refused here could
never have trained; one that passes may still run out later. Memory available is the host's
``MemAvailable`` (psutil when installed, else ``/proc/meminfo``) and, on a GPU, the device's
free memory as JAX reports it.
"""

from __future__ import annotations

import math
from pathlib import Path

import jax
import numpy as np

from vsgjax.config import Config, ConfigError
from vsgjax.envs import EnvSpec

STEP_BYTES = 4 + 1 + 1  # reward float32, is_first and is_terminal bool


def tree_bytes(tree) -> int:
    """Bytes of every array leaf of a pytree (of arrays or ``jax.ShapeDtypeStruct``)."""
    return sum(math.prod(leaf.shape) * np.dtype(leaf.dtype).itemsize
               for leaf in jax.tree_util.tree_leaves(tree) if hasattr(leaf, "shape"))


def host_step_bytes(spec: EnvSpec) -> int:
    """Bytes of one step in the host loop's replay: uint8 images, float32 vectors and
    actions, the reward and flags."""
    observation = sum(math.prod(shape) * (1 if len(shape) == 3 else 4)
                      for shape in spec.obs.shapes.values())
    return observation + 4 * spec.action_dim + STEP_BYTES


def host_replay_steps(config: Config, episode_steps: int) -> int:
    """The most steps a host-loop seed's replay holds: its capacity, or every step the run
    stores by ``train.steps`` (one agent step per ``env.action_repeat`` env steps, plus each
    episode's first observation) when that is fewer."""
    agent_steps = math.ceil(config.train.steps / config.env.action_repeat)
    stored = agent_steps + math.ceil(agent_steps / max(1, episode_steps - 1))
    return min(config.train.replay_capacity, stored)


def available_host_bytes() -> int | None:
    """Host memory available for new allocations now (None where it cannot be read)."""
    try:
        import psutil
    except ImportError:
        psutil = None
    if psutil is not None:
        return int(psutil.virtual_memory().available)
    try:
        text = Path("/proc/meminfo").read_text()
    except OSError:
        return None
    for line in text.splitlines():
        name, _, value = line.partition(":")
        if name == "MemAvailable":
            return int(value.split()[0]) * 1024
    return None


def available_device_bytes(device: jax.Device) -> int | None:
    """Free memory of an accelerator as JAX reports it; None for the CPU (host memory) or
    where the device reports none."""
    if device.platform == "cpu":
        return None
    stats = device.memory_stats() or {}
    if "bytes_limit" not in stats:
        return None
    return int(stats["bytes_limit"]) - int(stats.get("bytes_in_use", 0))


def size_text(count: int) -> str:
    """``count`` bytes in the largest binary unit that keeps at least 1 (``"2.79 TiB"``)."""
    units = ("B", "KiB", "MiB", "GiB", "TiB", "PiB")
    power = min(len(units) - 1, max(0, int(math.log(max(count, 1), 1024))))
    return f"{count / 1024**power:.3g} {units[power]}"


def check_fits(config: Config, seeds: int, on_device: dict[str, int],
               on_host: dict[str, int] | None = None, device: jax.Device | None = None) -> None:
    """ConfigError when what ``seeds`` seeds hold exceeds the memory available, naming the
    estimate, its parts and what is available. ``on_device``/``on_host``: name -> bytes of one
    seed on JAX's ``device`` (by default its first) and in host memory; on a CPU both are host
    memory."""
    device = device or jax.devices()[0]
    on_host = dict(on_host or {})
    free_device = available_device_bytes(device)
    places = [(on_device, free_device, f"{device.platform} device memory")]
    if free_device is None:
        places = [({**on_device, **on_host}, available_host_bytes(), "host memory")]
    else:
        places.append((on_host, available_host_bytes(), "host memory"))
    for parts, free, where in places:
        needed = seeds * sum(parts.values())
        if free is None or needed <= free:
            continue
        listed = ", ".join(f"{name} {size_text(count)}" for name, count in parts.items())
        per_seed = f", each x {seeds} seeds" if seeds > 1 else ""
        raise ConfigError(
            f"this run needs at least {size_text(needed)} of {where} ({listed}{per_seed}) but "
            f"{size_text(free)} is available (train.replay_capacity={config.train.replay_capacity} "
            "steps); valid: a smaller train.replay_capacity or model, fewer seeds per process, "
            "or a machine with more memory")
