"""The ``memory_len`` figure and tables: bsuite's memory test scored by bsuite's own analysis
code, success against the memory length L beside the published DreamerV3 and R2I points, and
the gate statistics beside the scores.

A run's memory length is its config's ``env.memory_length``; its series is its method with the
``-L<L>`` suffix dropped (``VSG-gatel0rd-L20`` is series ``VSG-gatel0rd`` at L = 20). Per run:

* bsuite's ``memory_len`` analysis (``bsuite.experiments.memory_len.analysis``) reads the
  training episodes, every one the run played (``episode/return`` lines of ``metrics.jsonl``,
  the random prefill's included, as bsuite counts an agent's every episode): the cumulative
  ``episode`` and ``total_perfect`` (episodes with reward +1). Its regret ratio at the last
  episode is the fraction of imperfect episodes over the 0.5 of a random agent, and L counts as
  learned below 0.75; bsuite's ``score`` is the fraction of lengths learned, per seed. bsuite
  trains 10,000 episodes per length: a run with fewer is scored at its last episode, a reduced
  budget the table names.
* success: the fraction of correct episodes (return +1) of the run's last evaluation (the
  actor's mode; ``(mean return + 1) / 2``), the quantity drawn against L.
* the gates (VSG and the other gated models): the last ``gates/*`` line of ``metrics.jsonl``:
  the open rate, the closed runs' 90th percentile and max against the geometric null of the same
  open rate, the units held closed across the gap (``gates/holding_<L>``) against independent
  gates, the units written at the cue and held to the query (``gates/written_and_held_<L>``),
  and the gate probability at the cue step against the other steps; the same over the live
  units only (those that opened in the logged batch: a dead unit looks held), where the run
  logged them. The nulls are computed here from the logged open rates (:func:`episode_nulls`),
  the same for every run whatever its logs hold: independent gates in windows of
  ``train.length`` steps over back-to-back episodes of L + 2 stored steps (the reset's and
  the L + 1 agent steps'), a window starting at any step of an episode.

* the cue units, where ``python -m experiments.cue_units`` wrote the run's record into the
  experiment's :data:`CUE_UNITS_DIR` (``<group>-s<seed>.json``) at the run's last evaluation
  step: the units that carry the cue to the query, those held closed to it, the cue-gated units
  and the readouts of the cue from the state (a record from an earlier checkpoint is left out,
  with a warning).

The published points (``published``: a file of ``experiments/reference_scores/``, ``{"source",
"records": [{"method", "xs": lengths, "ys": success}]}``) are drawn as they are. With a
``baseline`` series (e.g. ``DreamerV2``), each L where it and another series have 2 or more
seeds gets a verdict line: the difference of their mean success against the baseline's std
over seeds, the reports' rule (``experiments/report/compare.py``).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from experiments.report.compare import against_baseline
from experiments.report.context import Context
from experiments.report.runs import is_number, read_jsonl, warn
from experiments.report.style import colour, fmt, markdown_table, save_figure, write_missing_note
from experiments.spec import Run
from vsgjax.agents.dreamer.gate_statistics import (
    expected_closed_runs,
    geometric_null,
    null_holding_in,
    null_written_and_held,
    window_segments,
)
from vsgjax.config import Config
from vsgjax.loop.rundir import METRICS_FILE
from vsgjax.registry.agents import agent_entry

CUE_UNITS_DIR = "cue_units"  # the experiment's folder of experiments.cue_units records
CUE_KEYS = ("cue_units", "cue_units_held", "cue_gated_units", "readout_all", "readout_held",
            "actor_accuracy")
BSUITE_EPISODES = 10_000  # bsuite's sweep: training episodes per memory length
GATE_KEYS = ("open", "closed_run_p90", "null_run_p90", "closed_run_max", "null_run_max",
             "prob_step1", "prob_other_steps", "live_units", "open_live", "live_prob_step1",
             "live_prob_other_steps")


def gap_keys(length: int) -> tuple[str, ...]:
    """The gate keys of a memory gap of ``length`` steps."""
    return (f"holding_{length}", f"null_holding_{length}", f"live_holding_{length}",
            f"live_null_holding_{length}", f"written_and_held_{length}",
            f"null_written_and_held_{length}")


def episode_nulls(open_rate: float, live_rate: float | None, config: Config,
                  length: int) -> dict[str, float]:
    """The nulls of a gates line whose open rate (and live units' open rate) is given, for
    independent gates in the run's training windows over MemoryChain episodes of L + 2 stored
    steps (:func:`window_segments`): the closed runs' p90 and max (the batch's expected number
    of runs: ``train.batch`` windows of every gated unit), the units held across L, and those
    written at step 1 or 2 and held to step L + 1."""
    rows = window_segments(length + 2, config.train.length)
    segments = [s for row in rows for s in row]
    units = (config.model.stoch if agent_entry(config.agent).option("dynamics") == "SVSG"
             else config.model.deter)
    runs = config.train.batch * units * expected_closed_runs(open_rate, segments) / len(rows)
    null = geometric_null(open_rate, round(runs), segments)
    out = {"null_run_p90": null["p90"], "null_run_max": null["max"],
           f"null_holding_{length}": null_holding_in(open_rate, length, rows),
           f"null_written_and_held_{length}": null_written_and_held(open_rate,
                                                                    max(1, length - 1))}
    if live_rate is not None:
        out[f"live_null_holding_{length}"] = null_holding_in(live_rate, length, rows)
    return out


@dataclass
class SeedResult:
    """One run: its series, memory length and seed, its bsuite numbers, success and gates."""

    series: str
    length: int
    seed: int
    episodes: int  # training episodes played
    regret_ratio: float  # bsuite's, at the last training episode
    success: float  # the last evaluation's fraction of correct episodes
    wall_minutes: float
    gates: dict[str, float] = field(default_factory=dict)
    cue: dict[str, float | None] = field(default_factory=dict)  # its cue_units record's counts

    @property
    def learned(self) -> bool:
        from bsuite.experiments.memory_len.analysis import LEARNING_THRESH

        return self.regret_ratio < LEARNING_THRESH


@dataclass
class MemoryLenData:
    series: list[str]
    lengths: list[int]
    results: list[SeedResult]
    scores: dict[str, list[float]]  # series -> bsuite's score of each seed with every length
    published: dict[str, tuple[list[float], list[float]]]  # method -> (lengths, success)
    published_source: str
    missing: list[Run]
    baseline: str | None = None

    def of(self, series: str, length: int) -> list[SeedResult]:
        return [r for r in self.results if r.series == series and r.length == length]


def series_of(run: Run, length: int) -> str:
    """The run's method without its ``-L<length>`` suffix."""
    return re.sub(rf"-L{length}$", "", run.method)


def training_frame(returns: list[float], length: int):
    """bsuite's logging columns of a run's training episodes, one row per episode."""
    import pandas as pd

    perfect = np.cumsum(np.asarray(returns) > 0)
    return pd.DataFrame({"episode": np.arange(1, len(returns) + 1), "total_perfect": perfect,
                         "total_return": np.cumsum(returns), "memory_length": length})


def regret_ratio(frame) -> float:
    """bsuite's regret ratio at the frame's last episode (capped at bsuite's budget)."""
    from bsuite.experiments.memory_len.analysis import memory_preprocess

    frame = memory_preprocess(frame)
    last = min(int(frame.episode.max()), BSUITE_EPISODES)
    return float(frame.loc[frame.episode == last, "regret_ratio"].mean() / last)


def read_run(context: Context, run: Run) -> tuple[SeedResult, object] | None:
    """The run's result and bsuite frame, or None without training episodes or evaluations."""
    curve = context.records.scores(run)
    path = run.logdir(context.records.root) / METRICS_FILE
    if curve is None or not path.exists():
        return None
    lines = read_jsonl(path, context.records.problems)
    returns = [line["episode/return"] for line in lines if is_number(line.get("episode/return"))]
    if not returns:
        return None
    gate_lines = [line for line in lines if "gates/open" in line]
    length = run.config().env.memory_length
    gates = {}
    if gate_lines:
        last = gate_lines[-1]
        keys = (*GATE_KEYS, *gap_keys(length))
        gates = {key: float(last[f"gates/{key}"]) for key in keys
                 if is_number(last.get(f"gates/{key}"))}
        if "open" in gates:
            gates.update(episode_nulls(gates["open"], gates.get("open_live"), run.config(),
                                       length))
    frame = training_frame(returns, length)
    wall = float(curve.wall[-1]) / 60 if curve.wall is not None else float("nan")
    result = SeedResult(series_of(run, length), length, run.seed, len(returns),
                        regret_ratio(frame), (float(curve.ys[-1]) + 1) / 2, wall, gates,
                        read_cue_record(context, run, int(curve.xs[-1])))
    return result, frame


def read_cue_record(context: Context, run: Run, last_step: int) -> dict[str, float | None]:
    """The run's :data:`CUE_KEYS` from its ``experiments.cue_units`` record, if there is one
    measured at ``last_step`` (the run's last evaluation); ``{}`` otherwise."""
    path = (context.records.root / run.experiment / CUE_UNITS_DIR
            / f"{run.method_dir}-s{run.seed}.json")
    if not path.exists():
        return {}
    record = json.loads(path.read_text())
    if record.get("step") != last_step:
        warn(f"memory_len: {path} measured the checkpoint at env step {record.get('step')}, "
             f"the run ends at {last_step}: left out (run python -m experiments.cue_units again)",
             context.records.problems)
        return {}
    return {key: record.get(key) for key in CUE_KEYS}


def load_published(context: Context, name: str | None) -> tuple[dict, str]:
    if not name:
        return {}, ""
    data = json.loads((context.reference_dir / name).read_text())
    return ({record["method"]: (record["xs"], record["ys"]) for record in data["records"]},
            data.get("source", ""))


def memory_len_data(context: Context, published: str | None = None,
                    baseline: str | None = None) -> MemoryLenData:
    """Every run of the experiment scored, bsuite's score per series and seed; ``baseline``
    the series the others are compared with (a warning, and no verdicts, if there is none)."""
    from bsuite.experiments.memory_len.analysis import score

    results, frames, missing = [], {}, []
    for run in context.experiment.runs:
        read = read_run(context, run)
        if read is None:
            missing.append(run)
            continue
        result, frame = read
        results.append(result)
        frames.setdefault((result.series, result.seed), []).append(frame)
    series = list(dict.fromkeys(series_of(run, run.config().env.memory_length)
                                for run in context.experiment.runs))
    lengths = sorted({run.config().env.memory_length for run in context.experiment.runs})
    scores: dict[str, list[float]] = {}
    import pandas as pd

    for (name, _), parts in sorted(frames.items()):
        if len(parts) < len(lengths):
            continue  # bsuite's score is over the sweep's every length
        scores.setdefault(name, []).append(float(score(pd.concat(parts))))
    if missing:
        warn(f"memory_len: {len(missing)} runs have no training episodes or evaluation yet",
             context.records.problems)
    points, source = load_published(context, published)
    if baseline is not None and baseline not in series:
        warn(f"memory_len: baseline {baseline!r} is not a series of the experiment; valid: "
             f"{', '.join(series)}; no verdicts", context.records.problems)
        baseline = None
    return MemoryLenData(series, lengths, results, scores, points, source, missing, baseline)


def mean_std(values: list[float]) -> tuple[float, float]:
    return (float(np.mean(values)), float(np.std(values))) if values else (np.nan, np.nan)


def draw_memory_len(data: MemoryLenData, stem: Path) -> list[Path]:
    """Success against L: each series' mean ± std over seeds, the published points dashed."""
    figure = Figure(figsize=(6.4, 4.0), layout="constrained")
    ax = figure.subplots()
    names = [*data.series, *data.published]
    for name in data.series:
        xs = [L for L in data.lengths if data.of(name, L)]
        stats = [mean_std([r.success for r in data.of(name, L)]) for L in xs]
        if xs:
            ax.errorbar(xs, [s[0] for s in stats], yerr=[s[1] for s in stats], marker="o",
                        capsize=3, label=name, color=colour(name, names))
    for name, (xs, ys) in data.published.items():
        ax.plot(xs, ys, "--", marker="s", markersize=4, alpha=0.7, label=f"{name} (published)",
                color=colour(name, names))
    ax.axhline(0.5, color="grey", lw=0.8, ls=":")
    ax.set(xlabel="memory length L", ylabel="success (fraction of correct episodes)",
           ylim=(-0.02, 1.05), title="bsuite memory_len")
    ax.legend(fontsize=7)
    write_missing_note(ax, data.missing)
    return save_figure(figure, stem)


def _cell(results: list[SeedResult]) -> str:
    if not results:
        return "—"
    mean, std = mean_std([r.success for r in results])
    learned = sum(r.learned for r in results)
    return f"{mean:.2f} ± {std:.2f} ({len(results)}); learned {learned}/{len(results)}"


def memory_len_markdown(data: MemoryLenData) -> str:
    """The success and bsuite tables, the gates' table and the wall minutes."""
    budget = max((r.episodes for r in data.results), default=0)
    lines = ["Success at the last evaluation (mean ± std (seeds)); *learned*: seeds whose "
             "bsuite regret ratio at the last training episode is below 0.75 (bsuite's "
             f"threshold). Runs played up to {budget:,} training episodes against bsuite's "
             f"{BSUITE_EPISODES:,}: **a reduced budget**.", ""]
    rows = [["L", *data.series]]
    rows += [[str(L), *(_cell(data.of(name, L)) for name in data.series)]
             for L in data.lengths]
    lines += [markdown_table(rows), ""]
    lines += verdicts(data)
    rows = [["series", "bsuite memory_len score (per seed)", "mean"]]
    for name in data.series:
        values = data.scores.get(name, [])
        rows.append([name, ", ".join(f"{v:.2f}" for v in values) or "— (lengths missing)",
                     fmt(mean_std(values)[0]) if values else "—"])
    lines += ["bsuite's score: the fraction of the lengths learned, per seed with every "
              "length.", "", markdown_table(rows), ""]
    lines += gates_markdown(data)
    lines += cue_markdown(data)
    rows = [["L", *data.series]]
    rows += [[str(L), *(fmt(mean_std([r.wall_minutes for r in data.of(n, L)])[0], 1)
                        for n in data.series)] for L in data.lengths]
    lines += ["Wall minutes per run (mean over seeds; seeds trained together share a "
              "process).", "", markdown_table(rows)]
    return "\n".join(lines)


def verdicts(data: MemoryLenData) -> list[str]:
    """One line per L and series against the baseline, where both have 2 or more seeds."""
    if data.baseline is None:
        return []
    lines = []
    for L in data.lengths:
        base = [r.success for r in data.of(data.baseline, L)]
        if len(base) < 2:
            continue
        base_mean, base_std = mean_std(base)
        for name in data.series:
            ours = [r.success for r in data.of(name, L)]
            if name == data.baseline or len(ours) < 2:
                continue
            difference = mean_std(ours)[0] - base_mean
            lines.append(f"- L = {L}: {name} − {data.baseline} = {difference:+.2f} "
                         f"({data.baseline}'s std {base_std:.2f}): "
                         f"{against_baseline(difference, base_std)}.")
    return [*lines, ""] if lines else []


def gates_markdown(data: MemoryLenData) -> list[str]:
    gated = [r for r in data.results if r.gates]
    if not gated:
        return []
    rows = [["series", "L", "open", "closed run p90 (null)", "max (null)",
             "held across L (null)", "written at the cue, held to L (null)",
             "p(gate) cue step / others"]]
    live = [["series", "L", "live units", "open (live)", "held across L (null)",
             "p(gate) cue step / others"]]
    for name in data.series:
        for L in data.lengths:
            runs = [r for r in data.of(name, L) if r.gates]
            if not runs:
                continue
            m = {key: mean_std([r.gates.get(key, np.nan) for r in runs])[0]
                 for key in (*GATE_KEYS, *gap_keys(L))}
            rows.append([name, str(L), fmt(m["open"]),
                         f"{fmt(m['closed_run_p90'], 1)} ({fmt(m['null_run_p90'], 1)})",
                         f"{fmt(m['closed_run_max'], 0)} ({fmt(m['null_run_max'], 0)})",
                         f"{fmt(m[f'holding_{L}'], 3)} ({fmt(m[f'null_holding_{L}'], 3)})",
                         f"{fmt(m[f'written_and_held_{L}'], 3)} "
                         f"({fmt(m[f'null_written_and_held_{L}'], 3)})",
                         f"{fmt(m['prob_step1'])} / {fmt(m['prob_other_steps'])}"])
            live.append([name, str(L), fmt(m["live_units"]), fmt(m["open_live"]),
                         f"{fmt(m[f'live_holding_{L}'], 3)} "
                         f"({fmt(m[f'live_null_holding_{L}'], 3)})",
                         f"{fmt(m['live_prob_step1'])} / {fmt(m['live_prob_other_steps'])}"])
    return ["Gate statistics at the last log (mean over seeds): gates that hold show closed "
            "runs far above the geometric null, units held across the gap and units written "
            "at the cue (episode step 1 or 2) and held to the query above independent gates', "
            "and a gate probability at the cue step unlike the others'. Every null is that of "
            "independent gates at the logged open rate in the training windows' episodes "
            "(L + 2 stored steps each; episode starts cut runs); — where a run predates a "
            "statistic.", "",
            markdown_table(rows), "",
            "The live units only (those whose gate opened in the logged batch; a unit that "
            "never opens keeps its initial value and counts as held): their fraction, their "
            "open rate, the live units held across L against independent gates at that rate, "
            "and their gate probability at the cue step against the others (— where the runs "
            "predate these statistics).", "", markdown_table(live), ""]


def _per_seed(runs: list[SeedResult], key: str, digits: int = 0) -> str:
    return ", ".join(fmt(r.cue.get(key), digits) for r in runs)


def cue_markdown(data: MemoryLenData) -> list[str]:
    """Per series and L, each seed's cue units beside its success, where records exist."""
    rows = [["series", "L", "success", "cue units", "held to the query", "cue-gated units",
             "readout: all units", "readout: held cue units", "actor at the query"]]
    for name in data.series:
        for L in data.lengths:
            runs = [r for r in data.of(name, L) if r.cue]
            if runs:
                rows.append([name, str(L), ", ".join(fmt(r.success, 2) for r in runs),
                             *(_per_seed(runs, key) for key in CUE_KEYS[:3]),
                             *(_per_seed(runs, key, 2) for key in CUE_KEYS[3:])])
    if len(rows) == 1:
        return []
    return ["The cue units (`python -m experiments.cue_units`, per seed, at the last "
            "checkpoint, on held-out random-policy episodes): units of the state whose cue "
            "separation d' at the query is >= 1, those closed from step 3 to the query in >= 90% "
            "of the episodes, units whose gate opens at the cue with probabilities >= 0.5 apart "
            "under the two cues, a linear readout's held-out accuracy of the cue from the "
            "state (0.5: chance), and how often the actor's mode at the query takes the action "
            "the cue asks for (a state that holds the cue with an actor at 0.5: the actor "
            "failed, not the memory); — where a model has no gates or no held cue unit.", "",
            markdown_table(rows), ""]
