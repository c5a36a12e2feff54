"""Many seeds in one program, the batch over many devices.

S independent seeds train as one program: their agent states are stacked on a leading seed axis
(every leaf ``[S, ...]``) and :meth:`Agent.train_step` is ``vmap``-ped over it, so one update
of S seeds is one set of S-times-larger (batched) matmuls instead of S small ones; one seed
runs the plain update (:func:`seed_batched`). Seed ``k`` of the
stack computes exactly what a single-seed run of seed ``k`` computes (its own parameters,
batch and PRNG stream), to float tolerance.

Devices compose with seeds on one ``jax.sharding`` mesh with the axes ``("seed", "data")``::

    D devices, S seeds:  g = gcd(S, D) device groups along "seed", D / g devices along "data"

Seeds are spread first (no communication at all between them), then each seed's batch is
split along ``"data"`` with its parameters replicated: XLA's SPMD partitioner inserts the
all-reduce of the gradients. One device (any CPU run by default) is the mesh ``(1, 1)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from vsgjax.agents.interface import Agent
from vsgjax.config import Config, ConfigError

ACCELERATORS = ("gpu", "tpu")


def stack(trees: Sequence) -> object:
    """Trees of equal structure -> one tree whose leaves have a new leading axis."""
    return jax.tree.map(lambda *leaves: jnp.stack(leaves), *trees)


def take(tree, index):
    """Entry ``index`` (an int, or a list of ints to keep several) of a stacked tree."""
    if not isinstance(index, int):
        index = jnp.asarray(index, jnp.int32)
    return jax.tree.map(lambda leaf: leaf[index], tree)


def split_keys(keys: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``[S, 2]`` keys -> (next keys, keys to use): ``jax.random.split`` per seed."""
    pairs = jax.vmap(jax.random.split)(keys)
    return pairs[:, 0], pairs[:, 1]


def default_devices() -> int:
    """``train.devices=0``: every visible accelerator, or 1 where JAX runs on the CPU."""
    devices = jax.devices()
    return len(devices) if devices[0].platform in ACCELERATORS else 1


def resolve_devices(config: Config) -> int:
    """The device count of ``train.devices``; raises ConfigError for an impossible one."""
    requested = config.train.devices
    visible = len(jax.devices())
    if requested < 0 or requested > visible:
        platform = jax.devices()[0].platform
        hint = ("; on a CPU, XLA_FLAGS=--xla_force_host_platform_device_count=N splits it into N "
                "host devices" if platform == "cpu" else "")
        raise ConfigError(f"train.devices={requested}: this process sees {visible} device(s) "
                          f"({platform}); valid: 0 (all) to {visible}{hint}")
    return requested or default_devices()


def mesh_shape(num_seeds: int, devices: int, batch: int) -> tuple[int, int]:
    """(seed groups, data shards) of the mesh; raises ConfigError if the batch cannot split."""
    seed_groups = math.gcd(num_seeds, devices)
    data = devices // seed_groups
    if batch % data:
        raise ConfigError(
            f"train.devices={devices} with {num_seeds} seed(s) splits each batch over {data} "
            f"devices, which does not divide train.batch={batch}; valid: a device count whose "
            f"share of the batch, devices / gcd(seeds, devices), divides {batch}")
    return seed_groups, data


def seed_sharding(num_seeds: int, devices: int) -> NamedSharding:
    """The leading seed axis spread over ``gcd(num_seeds, devices)`` devices (the device loop's
    mesh: one compiled program holds a seed's whole loop, so only seeds are spread)."""
    groups = math.gcd(num_seeds, devices)
    return NamedSharding(Mesh(np.asarray(jax.devices()[:groups]), ("seed",)),
                         PartitionSpec("seed"))


def seed_batched(function, num_seeds: int):
    """``function`` over a leading seed axis of every argument and result: ``jax.vmap``, or for
    one seed the plain function on the squeezed axis (vmap over a size-1 axis turns the matmuls
    into slower batched ones)."""
    if num_seeds > 1:
        return jax.vmap(function)

    def one_seed(*args):
        result = function(*jax.tree.map(lambda leaf: leaf[0], args))
        return jax.tree.map(lambda leaf: leaf[None], result)

    return one_seed


class Parallel:
    """The agent's jitted update and acting policy over S stacked seeds on a device mesh."""

    def __init__(self, agent: Agent, num_seeds: int, devices: int):
        self.agent, self.num_seeds = agent, num_seeds
        shape = mesh_shape(num_seeds, devices, agent.config.train.batch)
        mesh = Mesh(np.asarray(jax.devices()[:devices]).reshape(shape), ("seed", "data"))
        self.mesh_shape = shape
        self.seeds = NamedSharding(mesh, PartitionSpec("seed"))
        self.batches = NamedSharding(mesh, PartitionSpec("seed", "data"))
        # The old state is donated: its buffers hold the new one (one state in memory, not two).
        self.train_step = jax.jit(seed_batched(agent.train_step, num_seeds),
                                  in_shardings=(self.seeds, self.batches, self.seeds),
                                  out_shardings=(self.seeds, self.seeds), donate_argnums=0)

    def put_state(self, state):
        """A stacked agent state (or any tree with a leading seed axis) placed on the mesh."""
        return jax.device_put(state, self.seeds)

    def put_batch(self, batches: Sequence[dict]):
        """One replay batch per seed -> the stacked ``[S, B, T, ...]`` batch on the mesh."""
        stacked = {key: np.stack([batch[key] for batch in batches]) for key in batches[0]}
        return jax.device_put(stacked, self.batches)

    def describe(self) -> str:
        seeds, data = self.mesh_shape
        return (f"{self.num_seeds} seed(s) in one program; mesh seed={seeds} x data={data} "
                f"over {seeds * data} device(s)")
