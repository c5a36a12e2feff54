"""Which units of a trained agent's state carry bsuite's MemoryChain cue to the query, and do
their gates write it and hold it?

    python -m experiments.cue_units RUN_DIR [RUN_DIR ...] [--episodes 1000] [--seed 0] [--out DIR]

For each run on ``gymnax_memory_len`` (a Dreamer model), the world model filters held-out
random-policy episodes (the recall probe's :func:`experiments.recall_probe.collect`: the cue,
±1, shown at stored steps 0 and 1), and each unit of the recurrent state (``deter``; SVSG's
``stoch``) is measured:

* ``dprime[t]``: the cue's separation at stored step ``t``, ``|m₊ − m₋| / √((v₊ + v₋)/2)``
  over the episodes of either cue;
* at the query, stored step ``L`` (the state the actor reads to choose the deciding action),
  the *cue units* are those with ``dprime ≥ 1``;
* for a gated model: ``P(open at step s | cue)`` at the write steps ``s = 1, 2`` (the gate of
  step ``t`` reads the posterior of ``t − 1``, so only these see the cue), and ``held``, the
  fraction of episodes in which the unit is closed at every step from 3 to ``L`` (runs with
  L >= 3 only): its value at the query is the one written by step 2.

A run's summary counts the cue units, those held in at least :data:`HELD_SHARE` of the
episodes, and the *cue-gated* units, whose gate opens at a write step with probabilities at
least :data:`CUE_GATED_GAP` apart under the two cues, against the largest gap of any unit
with the cues shuffled among the episodes (the null of gates that ignore the cue). The readout
accuracies fit a diagonal linear discriminant to the state at the query on the first half of
the episodes and score its sign on the second: from all units, and from the held cue units
only. ``actor_accuracy`` is how often the actor's mode at the query, from the same filtered
states, takes the action the cue asks for: a world model that holds the cue (readout 1) with
an actor at 0.5 has failed in its actor, not its memory. ``--out`` writes one JSON record a
run (``<group>-s<seed>.json``) and ``report.md``, the table of every record there.
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from pathlib import Path

import jax
import numpy as np

import vsgjax
from experiments.recall_probe import TASK, collect
from experiments.report.style import fmt
from vsgjax.envs.gymnax_tasks import OBS_KEY, MemoryChainTask
from vsgjax.registry.agents import gated_models

CONTEXT = 2  # the context's entry of MemoryChain's observation [countdown, query, context]
WRITE_STEPS = (1, 2)
FIRST_HELD_STEP = WRITE_STEPS[-1] + 1
CUE_UNIT_DPRIME = 1.0  # the two cues' state means a pooled std apart at the query
HELD_SHARE = 0.9
CUE_GATED_GAP = 0.5
TOP_UNITS = 8  # units listed per run, by their separation at the query
DEFAULT_EPISODES = 1000


def separation(state: np.ndarray, cue: np.ndarray) -> np.ndarray:
    """``[T, D]`` d' of the cue in ``state`` ``[B, T, D]`` (``cue`` ``[B]`` of ±1)."""
    plus, minus = state[cue > 0], state[cue < 0]
    pooled = np.sqrt((plus.var(0) + minus.var(0)) / 2)
    return np.abs(plus.mean(0) - minus.mean(0)) / np.maximum(pooled, 1e-6)


def readout_accuracy(state: np.ndarray, cue: np.ndarray, units: np.ndarray) -> float | None:
    """Held-out accuracy of a diagonal linear discriminant of the cue from ``state`` ``[B, U]``'s
    ``units``, fitted on the first half of the episodes, scored on the second; ``None`` without
    units."""
    if not len(units):
        return None
    half = len(cue) // 2
    fit, test = state[:half, units], state[half:, units]
    plus, minus = fit[cue[:half] > 0], fit[cue[:half] < 0]
    weight = (plus.mean(0) - minus.mean(0)) / np.maximum((plus.var(0) + minus.var(0)) / 2, 1e-6)
    score = (test - (plus.mean(0) + minus.mean(0)) / 2) @ weight
    return float((np.sign(score) == cue[half:]).mean())


def open_by_cue(gate: np.ndarray, cue: np.ndarray, step: int) -> tuple[np.ndarray, np.ndarray]:
    """``(P(open | +), P(open | −))`` ``[D]`` of the gates ``[B, T, D]`` at ``step``."""
    opened = gate[:, step] > 0
    return opened[cue > 0].mean(0), opened[cue < 0].mean(0)


def cue_gate_gap(gate: np.ndarray, cue: np.ndarray) -> np.ndarray:
    """``[D]``: the largest ``|P(open | +) − P(open | −)|`` over the write steps."""
    gaps = [np.abs(np.subtract(*open_by_cue(gate, cue, step))) for step in WRITE_STEPS]
    return np.max(gaps, 0)


def measure(state: np.ndarray, cue: np.ndarray, length: int, gate: np.ndarray | None,
            seed: int = 0) -> dict:
    """The record's measurements (no run metadata) of ``state`` ``[B, L + 2, D]``, ``cue``
    ``[B]`` and, for a gated model, ``gate`` ``[B, L + 2, D]`` (1 open, 0 closed)."""
    dprime = separation(state, cue)
    query = dprime[length]
    cue_units = np.flatnonzero(query >= CUE_UNIT_DPRIME)
    top = np.argsort(-query)[:TOP_UNITS]
    out = {
        "cue_units": len(cue_units),
        "max_dprime": float(query.max()),
        "readout_all": readout_accuracy(state[:, length], cue, np.arange(state.shape[-1])),
        "units": [{"unit": int(i), "dprime": float(query[i]),
                   "first_step": _first_step(dprime[:, i])} for i in top],
    }
    if gate is None:
        return out
    held = (gate[:, FIRST_HELD_STEP:length + 1] == 0).all(1).mean(0)  # [D]
    held_cue_units = cue_units[held[cue_units] >= HELD_SHARE]
    gap = cue_gate_gap(gate, cue)
    shuffled = np.random.default_rng(seed).permutation(cue)
    out.update({
        "units_held": int((held >= HELD_SHARE).sum()),
        "cue_units_held": len(held_cue_units),
        "cue_gated_units": int((gap >= CUE_GATED_GAP).sum()),
        "cue_gate_gap_max": float(gap.max()),
        "null_cue_gate_gap_max": float(cue_gate_gap(gate, shuffled).max()),
        "readout_held": readout_accuracy(state[:, length], cue, held_cue_units),
        "open": float((gate > 0).mean()),
    })
    by_step = {step: open_by_cue(gate, cue, step) for step in WRITE_STEPS}
    for row in out["units"]:
        unit = row["unit"]
        for step, (plus, minus) in by_step.items():
            row[f"open_step{step}"] = [float(plus[unit]), float(minus[unit])]
        row["held"] = float(held[unit])
        row["open"] = float((gate[:, :, unit] > 0).mean())
    return out


def _first_step(dprime: np.ndarray) -> int | None:
    """The first stored step at which a unit's separation reaches :data:`CUE_UNIT_DPRIME`."""
    above = np.flatnonzero(dprime >= CUE_UNIT_DPRIME)
    return int(above[0]) if len(above) else None


def held_out_episodes(run, episodes: int, seed: int) -> dict:
    """``episodes`` random-policy MemoryChain episodes at the run's L, under its observation key."""
    (key,) = run.world_model.obs_shape.keys
    batch = dict(collect(MemoryChainTask(run.config.env.memory_length),
                         jax.random.PRNGKey(seed), episodes))
    batch[key] = batch.pop(OBS_KEY)
    return batch


def cue_record(logdir: Path, episodes: int = DEFAULT_EPISODES, seed: int = 0) -> dict:
    """One run's JSON record. Raises ValueError naming the run's task or model when it is not a
    Dreamer model on ``gymnax_memory_len``."""
    run = vsgjax.load(logdir)
    config = run.config
    if config.env.task != TASK or not hasattr(run.params, "wm"):
        raise ValueError(f"run {logdir}: task {config.env.task!r}, model {config.agent!r}; "
                         f"valid: a Dreamer model (with a world model) on {TASK!r}")
    if config.env.memory_length < FIRST_HELD_STEP:
        raise ValueError(f"run {logdir}: env.memory_length={config.env.memory_length}; valid: "
                         f">= {FIRST_HELD_STEP} (a unit holds the cue from step "
                         f"{FIRST_HELD_STEP} to the query at step L)")
    batch = held_out_episodes(run, episodes, seed)
    posts, _ = vsgjax.observe(config, run.params.wm, batch,
                              jax.random.fold_in(jax.random.PRNGKey(seed), 1))
    state = np.asarray(getattr(posts, "deter", posts.stoch))
    state = state.reshape(*state.shape[:2], -1)
    gate = np.asarray(posts.gate) if config.agent in gated_models() else None
    (obs_key,) = run.world_model.obs_shape.keys
    cue = np.sign(np.asarray(batch[obs_key])[:, 0, CONTEXT])
    return {"run": f"{logdir.parent.name}/{logdir.name}", "model": config.agent,
            "gate_objective": config.wm.gate_objective if gate is not None else None,
            "memory_length": config.env.memory_length, "step": run.step,
            "episodes": episodes, "seed": seed,
            "actor_accuracy": actor_accuracy(run, posts, cue, seed),
            **measure(state, cue, config.env.memory_length, gate, seed)}


def actor_accuracy(run, posts, cue: np.ndarray, seed: int) -> float | None:
    """How often the actor's mode at the query (stored step L), from the filtered state, takes
    the action the cue asks for (the reward's +1); ``None`` for a run without an actor."""
    if run.params.actor is None:
        return None
    length = run.config.env.memory_length
    query = jax.tree.map(lambda x: x[:, length], posts)
    feat = jax.vmap(run.world_model.dynamics.feat)(query)
    action = run.actor_policy("eval")(feat, jax.random.PRNGKey(seed))
    return float((np.asarray(action).argmax(-1) == (cue > 0)).mean())


LEGEND = (
    "Per run, on held-out random-policy episodes (the record's `episodes`) filtered by its world "
    "model at its last checkpoint: `cue_units`, units of the recurrent state whose cue "
    "separation d' at the query (stored step L, read by the actor for the deciding action) "
    "is >= 1; "
    "`cue_units_held`, those closed at every step from 3 to L in >= 90% of the episodes "
    "(`units_held`: all such units, those that never open included); `cue_gated_units`, units "
    "whose gate opens at step 1 or 2 with probabilities >= 0.5 apart under the two cues, "
    "`cue_gate_gap_max` the largest such gap and `null_cue_gate_gap_max` the same with the "
    "cues shuffled; `readout_*`, the held-out accuracy of a linear readout of the cue from all "
    "units and from the held cue units only (0.5: chance); `actor_accuracy`, how often the "
    "actor's mode at the query, from the same states, takes the action the cue asks for.")
COLUMNS = ("actor_accuracy", "cue_units", "cue_units_held", "units_held", "cue_gated_units",
           "cue_gate_gap_max", "null_cue_gate_gap_max", "readout_all", "readout_held", "max_dprime")


def table(records: Sequence[dict]) -> str:
    """A markdown table, one row a record, by L and run."""
    lines = ["| run | L | " + " | ".join(COLUMNS) + " |",
             "|---|---|" + "---|" * len(COLUMNS)]
    for record in sorted(records, key=lambda r: (r["memory_length"], r["run"])):
        cells = [fmt(value, 0 if isinstance(value, int) else 2)
                 for value in map(record.get, COLUMNS)]
        lines.append(f"| {record_name(record)} | {record['memory_length']} | "
                     + " | ".join(cells) + " |")
    return "\n".join(lines)


def record_name(record: dict) -> str:
    """``<group>-s<seed>`` of the run ``<group>/s<seed>`` (its directory's last two parts)."""
    return record["run"].replace("/", "-")


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.cue_units",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("logdirs", nargs="+", type=Path)
    parser.add_argument("--episodes", type=int, default=DEFAULT_EPISODES)
    parser.add_argument("--seed", type=int, default=0, help="seed of the held-out episodes")
    parser.add_argument("--out", type=Path, default=None,
                        help="write <group>-s<seed>.json per run and report.md here")
    args = parser.parse_args(argv)
    if args.episodes < 4:
        print(f"error: --episodes {args.episodes}; valid: >= 4", file=sys.stderr)
        return 2
    records = []
    for logdir in args.logdirs:
        try:
            records.append(cue_record(logdir, args.episodes, args.seed))
        except (FileNotFoundError, ValueError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        for record in records:
            path = args.out / f"{record_name(record)}.json"
            path.write_text(json.dumps(record, indent=1) + "\n")
        records = [json.loads(p.read_text()) for p in sorted(args.out.glob("*.json"))]
        (args.out / "report.md").write_text(
            f"# Cue units (`python -m experiments.cue_units`)\n\n{LEGEND}\n\n"
            f"{table(records)}\n")
    print(table(records))
    return 0


if __name__ == "__main__":
    sys.exit(main())
