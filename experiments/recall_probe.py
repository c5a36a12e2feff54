"""The world-model recall probe: does a world model hold bsuite's MemoryChain cue?

Trains only the world model (no actor-critic) of a model and gate objective on random-policy
``gymnax_memory_len`` episodes and measures, on fresh held-out episodes, how often the sign of
the reward head's mean at the last step matches the true final reward (±1; chance 0.5):

* ``filtered``: from the posterior after observing the whole episode;
* ``open_loop``: after observing the first :data:`OBSERVED_STEPS` stored steps only, imagining
  the rest under the episode's recorded actions and reading the last imagined step.

An episode is stored as the device loop stores it: the reset observation and the L + 1 agent
steps (L + 2 steps, ``is_first`` at step 0, the final reward at step L + 1). ``action[t]`` is the
action that led to observation ``t`` and ``reward[t]`` the reward it earned, so the release's
convention (reward ``r_t`` predicted from state ``s_t``) reads the final reward from the state
that has seen the deciding action. For gated models the record adds gate statistics of the
held-out episodes (:mod:`vsgjax.agents.dreamer.gate_statistics`)::

    python -m experiments.recall_probe                                  # the default sweep
    python -m experiments.recall_probe --lengths 5,20 --variants dreamerv2,vsg:rate --seeds 0,1
    python -m experiments.recall_probe --lengths 10 --variants vsg:rate@wm.gate_lambda=0.05

One JSON record per (L, variant, seed) under ``--out``; existing records are kept (the sweep
resumes), and ``report.md`` there holds the table printed at the end and ``accuracy.png`` the
accuracy against L: every record under ``--out`` measured with the same settings, not only
this sweep's. docs/experiments.md,
"The recall probe", has what it measured.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import matplotlib
import numpy as np
from matplotlib.figure import Figure

import vsgjax
from experiments.report.style import save_figure
from vsgjax.agents.dreamer.api import world_model_for
from vsgjax.config import Config, ConfigError
from vsgjax.envs.gymnax_tasks import OBS_KEY, MemoryChainTask
from vsgjax.registry.agents import MODELS, dreamer_models, gated_models, prototype_models

TASK = "gymnax_memory_len"
DEFAULT_LENGTHS = (5, 10, 20, 40)
DEFAULT_VARIANTS = ("dreamerv2", "vsg:release", "vsg:rate", "vsg:gatel0rd", "vsg:rate_kl")
DEFAULT_UPDATES = 2000
DEFAULT_EVAL_EPISODES = 1000
DEFAULT_OUT = Path("experiments/results/recall_probe")
# Stored steps observed before open-loop imagination: the reset observation and the first
# step's, which both show the cue (bsuite's step t returns the observation of time t - 1).
OBSERVED_STEPS = 2
ACTIONS = 2


def probe_models() -> tuple[str, ...]:
    """The models the probe trains: Dreamer world models with a reward head read from a
    decoder-trained state (not the prototype models)."""
    return tuple(m for m in dreamer_models() if m not in prototype_models())


@dataclasses.dataclass(frozen=True)
class Variant:
    """A model, for a gated model its gate objective (``None``: the model's preset), and config
    overrides (``key=value``, e.g. ``wm.gate_lambda=0.05``)."""

    model: str
    objective: str | None = None
    overrides: tuple[str, ...] = ()

    @classmethod
    def parse(cls, text: str) -> Variant:
        """``model[:objective][@key=value...]``; the names are checked by :func:`probe_config`."""
        head, *overrides = text.strip().split("@")
        model, _, objective = head.partition(":")
        if (not model or ":" in objective or (_ and not objective)
                or any(not o.partition("=")[0] or not o.partition("=")[2] for o in overrides)):
            raise ConfigError(f"variant {text!r}; valid: 'model', 'model:objective', each "
                              f"optionally followed by '@key=value' overrides, e.g. "
                              f"{', '.join(DEFAULT_VARIANTS)}, vsg:rate@wm.gate_lambda=0.05")
        return cls(model, objective or None, tuple(overrides))

    @property
    def name(self) -> str:
        head = self.model if self.objective is None else f"{self.model}:{self.objective}"
        return "@".join((head, *self.overrides))


def probe_config(length: int, variant: Variant, seed: int, size: str = "cpu") -> Config:
    """The config of one probe: ``gymnax_memory_len`` at ``size``, one whole stored episode
    (L + 2 steps) per training sequence. Raises ConfigError naming a bad value and the valid
    ones (make_config's checks, and models the probe cannot train)."""
    if variant.model in MODELS and variant.model not in probe_models():
        raise ConfigError(f"model {variant.model!r} has no decoder-trained world model to probe; "
                          f"valid: {', '.join(probe_models())}")
    overrides = [f"env.memory_length={length}", f"train.length={length + 2}",
                 f"train.seed={seed}"]
    if variant.objective is not None:
        overrides.append(f"wm.gate_objective={variant.objective}")
    own = {o.partition("=")[0] for o in overrides} | {"wm.gate_objective"}
    for override in variant.overrides:
        if override.partition("=")[0] in own:
            raise ConfigError(f"variant {variant.name!r} overrides {override.partition('=')[0]}, "
                              "which the probe sets itself; valid: any other key (the length "
                              "is --lengths, the seed --seeds, the gate objective "
                              "'model:objective')")
    return vsgjax.make_config(TASK, variant.model, size, [*overrides, *variant.overrides])


@functools.partial(jax.jit, static_argnames=("task", "count"))
def collect(task: MemoryChainTask, key: jax.Array, count: int) -> dict:
    """``count`` random-policy episodes ``[count, L + 2, ...]`` as the device loop stores them
    (step 0 the reset observation with a zero action; uniform one-hot actions after)."""

    def episode(key):
        reset_key, action_key = jax.random.split(key)
        start = task.reset(reset_key)
        actions = jax.nn.one_hot(
            jax.random.randint(action_key, (task.episode_steps,), 0, ACTIONS), ACTIONS)

        def step(state, action):
            state = task.step(state, action)
            return state, (state.obs[OBS_KEY], state.reward, state.is_terminal)

        _, (obs, reward, terminal) = jax.lax.scan(step, start, actions)
        first = jnp.arange(task.episode_steps + 1) == 0
        return {
            OBS_KEY: jnp.concatenate([start.obs[OBS_KEY][None], obs]),
            "action": jnp.concatenate([jnp.zeros((1, ACTIONS)), actions]),
            "reward": jnp.concatenate([jnp.zeros(1), reward]),
            "is_first": first,
            "is_terminal": jnp.concatenate([jnp.zeros(1, bool), terminal]),
        }

    return jax.vmap(episode)(jax.random.split(key, count))


@functools.partial(jax.jit, static_argnames="config")
def recall(config: Config, params: dict, batch: dict, key: jax.Array) -> dict:
    """Accuracy of the final reward's sign, filtered and open loop, and the mean |predicted
    reward| at the steps whose reward is 0 (the reward head's time alignment)."""
    observe_key, imagine_key = jax.random.split(key)
    posts, _ = vsgjax.observe(config, params, batch, observe_key)
    model = world_model_for(config, params, ACTIONS)
    predicted = model.reward_mean(params, jax.vmap(jax.vmap(model.dynamics.feat))(posts))
    start = jax.tree.map(lambda x: x[:, OBSERVED_STEPS - 1], posts)
    horizon = batch["action"].shape[1] - OBSERVED_STEPS
    dreamed = vsgjax.imagine(params, start, horizon, config=config, key=imagine_key,
                             actions=batch["action"][:, OBSERVED_STEPS:])
    truth = jnp.sign(batch["reward"][:, -1])
    return {
        "accuracy_filtered": (jnp.sign(predicted[:, -1]) == truth).mean(),
        "accuracy_open_loop": (jnp.sign(dreamed["rewards"][:, -1]) == truth).mean(),
        "reward_abs_before_last": jnp.abs(predicted[:, :-1]).mean(),
    }


# A record's gate statistic -> its GateStatistics.summary key (``{gap}``: the cue's gap L - 1,
# ``{length}``: the memory gap L).
RECORD_KEYS = {
    "open": "open", "steps_any_open": "steps_any_open", "units_ever_open": "units_ever_open",
    **{f"{kind}_run_{q}": f"{kind}_run_{q}" for kind in ("closed", "null")
       for q in ("mean", "p90", "max")},
    "holding": "holding_{gap}", "null_holding": "null_holding_{gap}",
    "prob_step1": "prob_step1", "prob_other": "prob_other_steps",
    "live_units": "live_units", "open_live": "open_live",
    "live_holding": "live_holding_{gap}", "live_null_holding": "live_null_holding_{gap}",
    "live_prob_step1": "live_prob_step1", "live_prob_other": "live_prob_other_steps",
    "written_and_held": "written_and_held_{length}",
    "null_written_and_held": "null_written_and_held_{length}",
}


def gate_record(config: Config, params: dict, batch: dict, key: jax.Array) -> dict[str, float]:
    """Gate statistics of held-out episodes: open fraction, closed runs against the geometric
    null, units closed across the gap, and the gate probability at step 1 (the gate that can
    store the cue shown at step 0) against the other steps; the last two also over the live
    units only (``live_*``: units that never open look held); the units written at step 1 or 2
    and kept closed to the last step (``written_and_held``), against independent gates."""
    stats = vsgjax.gate_statistics(params, batch, key, config=config)
    length = config.env.memory_length
    # The cue is shown at stored steps 0 and 1 and needed at step L + 1: a unit written at
    # step 2 (from step 1's posterior) holds it if it stays closed for the L - 1 steps after.
    gap = max(1, length - 1)
    summary = stats.summary(gaps=[gap], memory_gap=length)
    out = {name: summary.get(f"gates/{key}".format(gap=gap, length=length), math.nan)
           for name, key in RECORD_KEYS.items()}
    out["gap"] = gap
    return {k: (v if math.isfinite(v) else None) for k, v in out.items()}


def run_probe(length: int, variant: Variant, seed: int, updates: int,
              eval_episodes: int, size: str = "cpu") -> dict:
    """Train one world model and measure it: the JSON record (deterministic but ``wall_s``)."""
    config = probe_config(length, variant, seed, size)
    began = time.perf_counter()
    task = MemoryChainTask(length)
    init_key, data_key, train_key, eval_key = jax.random.split(jax.random.PRNGKey(seed), 4)
    state = vsgjax.init(config, init_key, obs_shape={OBS_KEY: (3,)}, action_dim=ACTIONS)
    metrics = {}
    for update in range(updates):
        batch = collect(task, jax.random.fold_in(data_key, update), config.train.batch)
        state, metrics, _ = vsgjax.world_model_step(config, state, batch,
                                                    jax.random.fold_in(train_key, update))
    held_out = collect(task, jax.random.fold_in(eval_key, 0), eval_episodes)
    probe_key, gate_key = jax.random.split(jax.random.fold_in(eval_key, 1))
    record = {
        "task": TASK, "memory_length": length, "variant": variant.name, "model": variant.model,
        "gate_objective": config.wm.gate_objective if variant.model in gated_models() else None,
        "overrides": list(variant.overrides),
        "seed": seed, "size": size, "updates": updates, "batch": config.train.batch,
        "sequence_length": config.train.length, "eval_episodes": eval_episodes,
        "observed_steps": OBSERVED_STEPS,
        **{k: float(v) for k, v in recall(config, state.params, held_out, probe_key).items()},
        "final_metrics": {k: float(v) for k, v in metrics.items()},
        "gates": (gate_record(config, state.params, held_out, gate_key)
                  if variant.model in gated_models() else None),
    }
    record["wall_s"] = round(time.perf_counter() - began, 1)
    return record


def record_path(out: Path, length: int, variant: Variant, seed: int) -> Path:
    name = variant.name.replace(":", "-").replace("@", "-")
    return out / f"L{length}-{name}-s{seed}.json"


SETTINGS = ("updates", "eval_episodes", "size")  # a kept record must match these


def sweep(lengths: Sequence[int], variants: Sequence[Variant], seeds: Sequence[int],
          updates: int, eval_episodes: int, out: Path, size: str = "cpu",
          log=print) -> list[dict]:
    """Run every missing (L, variant, seed) record, keep the existing ones; return all of them.

    Every config is checked before anything is written; a kept record trained with other
    settings is refused (naming them) rather than mixed into the table."""
    for name, value in (("updates", updates), ("eval episodes", eval_episodes)):
        if value < 1:
            raise ConfigError(f"{name}={value}; valid: >= 1")
    cells = [(length, variant, seed) for length in lengths for variant in variants
             for seed in seeds]
    for cell in cells:
        probe_config(*cell, size)
    settings = {"updates": updates, "eval_episodes": eval_episodes, "size": size}
    kept = {}
    for cell in cells:
        path = record_path(out, *cell)
        if path.exists():
            kept[cell] = json.loads(path.read_text())
            differ = {k: kept[cell][k] for k in SETTINGS if kept[cell][k] != settings[k]}
            if differ:
                raise ConfigError(f"{path} was measured with {differ}, not {settings}; valid: "
                                  "the same settings, or another --out")
    out.mkdir(parents=True, exist_ok=True)
    records = []
    for cell in cells:
        path = record_path(out, *cell)
        if cell in kept:
            log(f"kept {path}")
            records.append(kept[cell])
            continue
        record = run_probe(*cell, updates, eval_episodes, size)
        tmp = path.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(record, indent=1) + "\n")
        tmp.replace(path)
        log(f"wrote {path} ({record['wall_s']} s): filtered {record['accuracy_filtered']:.3f}, "
            f"open loop {record['accuracy_open_loop']:.3f}")
        records.append(record)
    return records


def all_records(out: Path, settings: dict) -> list[dict]:
    """Every record under ``out`` measured with ``settings`` (:data:`SETTINGS`), ordered by L,
    then the default variants in their order, then the others by name, then seed."""
    records = [json.loads(path.read_text()) for path in out.glob("L*-s*.json")]
    order = {name: i for i, name in enumerate(DEFAULT_VARIANTS)}
    return sorted((r for r in records if all(r[k] == settings[k] for k in SETTINGS)),
                  key=lambda r: (r["memory_length"], order.get(r["variant"], len(order)),
                                 r["variant"], r["seed"]))


def _cell(values: list[float | None], digits: int = 2) -> str:
    values = [v for v in values if v is not None]
    if not values:
        return "-"
    text = f"{np.mean(values):.{digits}f}"
    return text + (f" ± {np.std(values):.{digits}f}" if len(values) > 1 else "")


def table(records: Sequence[dict]) -> str:
    """Markdown table: one row per (L, variant), means (± std over seeds)."""
    head = ("| L | variant | seeds | acc. filtered | acc. open loop | mean abs r̂ before last "
            "| open | closed run mean "
            "(null) | closed run max (null) | holding L-1 (null) | p(step 1) / p(other) "
            "| live units | written at 1-2, held L-1 (null) |")
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    groups: dict[tuple[int, str], list[dict]] = {}
    for r in records:
        groups.setdefault((r["memory_length"], r["variant"]), []).append(r)
    for (length, name), group in groups.items():
        gates = [r["gates"] for r in group if r["gates"]]
        row = [str(length), name, str(len(group)),
               _cell([r["accuracy_filtered"] for r in group]),
               _cell([r["accuracy_open_loop"] for r in group]),
               _cell([r["reward_abs_before_last"] for r in group]), *_gate_cells(gates)]
        lines.append("| " + " | ".join(row) + " |")
    return "\n".join(lines)


def draw_accuracy(records: Sequence[dict], stem: Path) -> list[Path]:
    """Accuracy against L, one line per variant (mean ± std over seeds): filtered on the left,
    open loop on the right; ``stem``.png and .pdf."""
    figure = Figure(figsize=(11, 4.2), layout="constrained")
    axes = figure.subplots(1, 2, sharey=True)
    variants = list(dict.fromkeys(r["variant"] for r in records))
    for ax, key, title in zip(axes, ("accuracy_filtered", "accuracy_open_loop"),
                              ("filtered", f"open loop after {OBSERVED_STEPS} steps"),
                              strict=True):
        for i, variant in enumerate(variants):
            lengths = sorted({r["memory_length"] for r in records if r["variant"] == variant})
            values = [[r[key] for r in records
                       if r["variant"] == variant and r["memory_length"] == length]
                      for length in lengths]
            ax.errorbar(lengths, [np.mean(v) for v in values], yerr=[np.std(v) for v in values],
                        marker="o", capsize=3, label=variant,
                        color=matplotlib.colormaps["tab20"](i % 20))
        ax.axhline(0.5, color="grey", lw=0.8, ls=":")
        ax.set(xlabel="memory length L", title=title, ylim=(0.4, 1.02))
    axes[0].set_ylabel("accuracy of the final reward's sign")
    figure.legend(*axes[0].get_legend_handles_labels(), loc="outside right", fontsize=7)
    return save_figure(figure, stem)


def _gate_cells(gates: Sequence[dict]) -> list[str]:
    """The gate columns of one table row ("-" for a gateless model)."""
    if not gates:
        return ["-"] * 7

    def pick(key: str, digits: int = 2) -> str:
        return _cell([g.get(key) for g in gates], digits)  # older records lack some keys

    return [pick("open"),
            f"{pick('closed_run_mean', 1)} ({pick('null_run_mean', 1)})",
            f"{pick('closed_run_max', 0)} ({pick('null_run_max', 0)})",
            f"{pick('holding')} ({pick('null_holding')})",
            f"{pick('prob_step1')} / {pick('prob_other')}",
            pick("live_units"),
            f"{pick('written_and_held', 3)} ({pick('null_written_and_held', 3)})"]


def _ints(text: str) -> list[int]:
    try:
        return [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}; valid: comma-separated integers") from None


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m experiments.recall_probe",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--lengths", type=_ints, default=list(DEFAULT_LENGTHS),
                        help="memory lengths L (default %(default)s)")
    parser.add_argument("--variants", default=",".join(DEFAULT_VARIANTS),
                        help="model[:gate objective][@key=value...], comma-separated "
                             "(default %(default)s)")
    parser.add_argument("--seeds", type=_ints, default=[0], help="default %(default)s")
    parser.add_argument("--updates", type=int, default=DEFAULT_UPDATES,
                        help="world-model updates per probe (default %(default)s)")
    parser.add_argument("--eval-episodes", type=int, default=DEFAULT_EVAL_EPISODES,
                        help="held-out episodes (default %(default)s)")
    parser.add_argument("--size", default="cpu", help="config size (default %(default)s)")
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT, help="default %(default)s")
    args = parser.parse_args(argv)
    try:
        variants = [Variant.parse(v) for v in args.variants.split(",")]
        sweep(args.lengths, variants, args.seeds, args.updates, args.eval_episodes, args.out,
              args.size)
    except ConfigError as error:
        parser.error(str(error))
    settings = {"updates": args.updates, "eval_episodes": args.eval_episodes, "size": args.size}
    records = all_records(args.out, settings)
    report = table(records)
    draw_accuracy(records, args.out / "accuracy")
    (args.out / "report.md").write_text(
        "# Recall probe\n\nAccuracy of the final reward's sign on held-out random-policy "
        f"episodes (chance 0.5); {args.updates} updates, {args.eval_episodes} episodes, size "
        f"{args.size}, open loop after {OBSERVED_STEPS} observed steps. "
        "docs/experiments.md, \"The recall probe\", explains the columns.\n\n"
        "![accuracy against L](accuracy.png)\n\n" + report + "\n")
    print(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
