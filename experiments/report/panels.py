"""The ``panels`` figure and table: named comparison panels, each one task and the methods it
compares (return against env steps, mean ± std over seeds), a table at given env steps with the
gated methods' gate statistics, and for each ``[ours, baseline]`` pair a panel compares a
verdict at the last of those steps; each ``[[figures.memory_rule]]`` table adds the control
rule's verdict for one variant (``experiments/report/memory_rule.py``).

A ``[[figures]]`` entry ``kind = "panels"`` has ``at`` (env steps) and ``[[figures.panels]]``
tables ``{title, task, methods, compare}`` (``title`` defaults to the task; a method written
``<experiment>/<method>`` is another experiment's, e.g. ``cpu_proprio/DreamerV2`` for the fully
observed baseline; ``compare`` is optional: one ``[ours, baseline]`` pair or a list of them). A
value at a step is the evaluation nearest to it and at most one grid bin away (the bars' rule).
The gate columns are the mean over seeds of each seed's last ``gates/open``,
``gates/closed_run_mean``, ``gates/prob_post_std`` and ``gates/kl`` in its ``metrics.jsonl``
(VSG and SVSG log them; others read —), beside ``1 / open``, the closed run that independent
gates would give. With ``holding_gap = N`` the table adds the columns that show holding: the
closed runs' 90th percentile and max beside the geometric null's, GateL0RD's two other rates
and the fraction of units closed across ``N`` steps (``gates/holding_N``) beside the chance of
that for independent gates (``gates/null_holding_N``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import matplotlib.ticker
from matplotlib.figure import Figure

from experiments.report.binning import Stat, binned, seed_stats, value_near
from experiments.report.compare import against_baseline
from experiments.report.context import Context
from experiments.report.memory_rule import MemoryRule, memory_rule_line, read_memory_rules
from experiments.report.runs import Curve, is_number, read_jsonl, warn
from experiments.report.style import (
    colour,
    fmt,
    hide_unused,
    markdown_table,
    panel_grid,
    save_figure,
    step_label,
    write_missing_note,
)
from experiments.spec import ExperimentError, Run
from vsgjax.loop.rundir import METRICS_FILE

GATE_KEYS = ("gates/open", "gates/closed_run_mean", "gates/prob_post_std", "gates/kl")
GATE_DIGITS = {"gates/open": 2, "gates/closed_run_mean": 1, "gates/prob_post_std": 3,
               "gates/kl": 3}
# The holding columns (``holding_gap``): (header, key), the gap's key added after them.
HOLDING_COLUMNS = (("closed-run p90", "gates/closed_run_p90"),
                   ("null p90", "gates/null_run_p90"),
                   ("closed-run max", "gates/closed_run_max"),
                   ("null max", "gates/null_run_max"),
                   ("steps with a unit open", "gates/steps_any_open"),
                   ("units ever open", "gates/units_ever_open"))
HOLDING_DIGITS = {"gates/closed_run_p90": 1, "gates/null_run_p90": 1,
                  "gates/closed_run_max": 1, "gates/null_run_max": 1}
NO_RUNS = "no runs yet"


@dataclass
class Panel:
    """One axes of the figure: a task and the methods drawn on it."""

    title: str
    task: str
    methods: list[str]
    compare: tuple[tuple[str, str], ...]  # (ours, baseline) pairs, a verdict each


@dataclass
class PanelsData:
    panels: list[Panel]
    seeds: dict[tuple[str, str], list[Curve]]  # (task, method) -> its seeds with scores
    gates: dict[tuple[str, str], dict[str, Stat]]  # (task, method) -> gate key -> over seeds
    missing: list[Run]
    spacing: float
    at: list[float]
    rules: list[MemoryRule]
    holding_gap: int | None = None  # a gap (steps): add the holding columns


    @property
    def methods(self) -> list[str]:
        """Every panel's methods in order of first appearance: a method keeps its colour in
        every panel."""
        return list(dict.fromkeys(m for panel in self.panels for m in panel.methods))


def read_panels(entries, problems: list[str] | None = None) -> list[Panel]:
    """The panels of a figure entry's ``panels`` list; one without a task or methods is skipped
    and a ``compare`` pair that is not two of its methods dropped, each with a warning."""
    panels = []
    for index, entry in enumerate(entries):
        task, methods = entry.get("task"), list(entry.get("methods", ()))
        title = entry.get("title", task)
        if not task or not methods:
            warn(f"panels: panel {index} ({title!r}) has no task or no methods; skipped",
                 problems)
            continue
        pairs = entry.get("compare") or []
        if pairs and isinstance(pairs[0], str):
            pairs = [pairs]
        compare = []
        for pair in pairs:
            if isinstance(pair, str) or len(pair) != 2 or not set(pair) <= set(methods):
                warn(f"panels: panel {title!r}: compare must be two of its methods (or a list "
                     f"of such pairs), got {pair!r}; no verdict", problems)
                continue
            compare.append(tuple(pair))
        panels.append(Panel(title, task, methods, tuple(compare)))
    return panels


def holding_keys(gap: int) -> tuple[str, str]:
    """The logged fractions of units closed across ``gap`` steps: measured, and for
    independent gates with the same open rate."""
    return f"gates/holding_{gap}", f"gates/null_holding_{gap}"


def gate_keys(holding_gap: int | None) -> tuple[str, ...]:
    """The ``gates/*`` keys the table reads."""
    if holding_gap is None:
        return GATE_KEYS
    return (*GATE_KEYS, *(key for _, key in HOLDING_COLUMNS), *holding_keys(holding_gap))


def read_holding_gap(value, problems: list[str] | None = None) -> int | None:
    """A figure's ``holding_gap``: a whole number of steps >= 1, or None (no holding columns;
    a bad value is warned about)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int) or value < 1:
        warn(f"panels: holding_gap must be a whole number of steps >= 1, got {value!r}; no "
             "holding columns", problems)
        return None
    return value


def last_gate_values(path: Path, problems: list[str] | None = None,
                     keys: tuple[str, ...] = GATE_KEYS) -> dict[str, float]:
    """Each gate key's last logged number in a ``metrics.jsonl`` (keys never logged are
    absent; so is everything when the file is)."""
    if not path.exists():
        return {}
    last = {}
    for record in read_jsonl(path, problems):
        last.update({key: float(record[key]) for key in keys if is_number(record.get(key))})
    return last


def gate_stats(context: Context, runs: list[Run],
               keys: tuple[str, ...] = GATE_KEYS) -> dict[str, Stat]:
    """Per gate key: mean ± std over the runs of each one's last logged value (a directory
    that holds another run is not counted)."""
    values = [last_gate_values(run.logdir(context.records.root) / METRICS_FILE,
                               context.records.problems, keys)
              for run in runs if not context.records.differs(run)]
    return {key: Stat.of(value.get(key) for value in values) for key in keys}


def panels_data(context: Context, entries=(), at=(), rule_entries=(),
                holding_gap=None) -> PanelsData:
    """The seeds with scores and the gate statistics of every panel's and memory rule's task x
    method; a method the experiment (or the one it names) has no runs of on that task is
    warned about. ``holding_gap``: the figure's (:func:`read_holding_gap`)."""
    panels = read_panels(entries, context.records.problems)
    rules = read_memory_rules(rule_entries, context.records.problems)
    gap = read_holding_gap(holding_gap, context.records.problems)
    keys = gate_keys(gap)
    wanted = [(panel.title, panel.task, method) for panel in panels for method in panel.methods]
    wanted += [(rule.title, rule.task, method) for rule in rules for method in rule.methods]
    seeds, gates, missing = {}, {}, []
    for title, task, method in wanted:
        key = (task, method)
        if key in seeds:
            continue
        try:
            runs = context.runs_of(*key)
            why = f"the experiment has no runs of {method} on {task}"
        except ExperimentError as error:
            runs, why = [], f"{method}: {error}"
        if not runs:
            warn(f"panels: {title!r}: {why}", context.records.problems)
        seeds[key], absent = context.scored(runs)
        gates[key] = gate_stats(context, runs, keys)
        missing.extend(absent)
    return PanelsData(panels, seeds, gates, missing, context.spacing, [float(x) for x in at],
                      rules, gap)


def draw_panel(ax, panel: Panel, data: PanelsData) -> None:
    """One panel's mean ± std lines, its missing-runs note (or "no runs yet"), its labels."""
    for method in panel.methods:
        seeds = data.seeds.get((panel.task, method), [])
        if not seeds:
            continue
        c = colour(method, data.methods)
        x, mean, std, _ = seed_stats(binned(s, data.spacing) for s in seeds)
        ax.plot(x, mean, color=c, lw=1.5, label=f"{method} (n={len(seeds)})")
        ax.fill_between(x, mean - std, mean + std, color=c, alpha=0.2, lw=0)
    if ax.lines:
        ax.legend(fontsize=6, loc="lower right")
    else:
        ax.text(0.5, 0.5, NO_RUNS, transform=ax.transAxes, ha="center", color="gray")
    absent = [r for r in data.missing if r.task == panel.task and r.method in panel.methods]
    write_missing_note(ax, absent)
    ax.set_title(f"{panel.title}\n({panel.task})", fontsize=8)
    ax.set_xlabel("env steps", fontsize=8)
    ax.set_ylabel("eval return", fontsize=8)
    ax.xaxis.set_major_formatter(matplotlib.ticker.FuncFormatter(
        lambda value, _: step_label(value)))
    ax.tick_params(labelsize=7)
    ax.grid(alpha=0.3)


def draw_panels(data: PanelsData, stem: Path, title: str = "") -> list[Path]:
    """One axes per panel, up to 4 a row."""
    rows, columns = panel_grid(len(data.panels))
    figure = Figure(figsize=(3.4 * columns, 3.0 * rows + 0.5), layout="constrained")
    axes = figure.subplots(rows, columns, squeeze=False)
    for index, panel in enumerate(data.panels):
        draw_panel(axes[index // columns][index % columns], panel, data)
    hide_unused(axes, len(data.panels), rows, columns)
    figure.suptitle(title or "eval return (mean ± std over seeds)", fontsize=10)
    return save_figure(figure, stem)


def stat_at(data: PanelsData, task: str, method: str, at: float) -> Stat:
    return Stat.of(value_near(c, at, data.spacing) for c in data.seeds.get((task, method), []))


def value_cells(data: PanelsData, task: str, method: str) -> list[str]:
    """The method's ``mean ± std (n)`` at each ``at`` step; "no runs yet" without scores,
    — where no seed has an evaluation near the step."""
    if not data.seeds.get((task, method)):
        return [NO_RUNS] * len(data.at)
    stats = [stat_at(data, task, method, at) for at in data.at]
    return [stat.text(1) if stat.n else "—" for stat in stats]


def gate_cells(data: PanelsData, task: str, method: str) -> list[str]:
    """Open fraction, closed-run length, ``1 / open``, the gate probability's spread and the
    gate KL: each key's mean over seeds (— where no seed logged it; ``(n=k)`` where only k of
    the method's seeds with scores did). ``1 / open`` is the mean closed run of gates that open
    independently at each step with the same probability (geometric lengths): a logged run near
    it means the gates hold nothing longer than coin flips would. A spread near 0 means the
    probability hardly depends on the state. The gate KL to Bernoulli(kappa), summed over
    units, is what the sparsity loss holds at ``wm.gate_free``."""
    stats = data.gates[(task, method)]
    seeds = len(data.seeds.get((task, method), []))

    def cell(key: str) -> str:
        partial = f" (n={stats[key].n})" if 0 < stats[key].n < seeds else ""
        return fmt(stats[key].mean, GATE_DIGITS[key]) + partial

    open_ = stats["gates/open"].mean
    independent = 1 / open_ if open_ else math.inf  # never open: one endless closed run
    cells = [cell("gates/open"), cell("gates/closed_run_mean"),
             fmt(independent, GATE_DIGITS["gates/closed_run_mean"]),
             cell("gates/prob_post_std"), cell("gates/kl")]
    if data.holding_gap is None:
        return cells
    holding = [key for _, key in HOLDING_COLUMNS] + list(holding_keys(data.holding_gap))
    return cells + [fmt(stats[key].mean, HOLDING_DIGITS.get(key, 2))
                    + (f" (n={stats[key].n})" if 0 < stats[key].n < seeds else "")
                    for key in holding]


def verdict(data: PanelsData, panel: Panel, pair: tuple[str, str]) -> str:
    """At the last ``at`` step: ours − baseline, and whether ours is above the baseline by more
    than the baseline's std, within it, or below it by more ("not enough runs" below 2 seeds
    a side)."""
    ours, baseline = pair
    at = data.at[-1]
    a, b = (stat_at(data, panel.task, m, at) for m in pair)
    where = f"{panel.title}, at {step_label(at)} env steps"
    if a.n < 2 or b.n < 2:
        return (f"{where}: not enough runs to compare {ours} (n={a.n}) with {baseline} "
                f"(n={b.n}).")
    difference = a.mean - b.mean
    return (f"{where}: {ours} − {baseline} = {difference:+.1f} ({baseline}'s std "
            f"{b.std:.1f}): {against_baseline(difference, b.std)}.")


def panels_markdown(data: PanelsData) -> str:
    """Per panel x method: the values at the ``at`` steps and the gate columns; then the
    verdict of every panel with ``compare`` and of every memory rule."""
    header = ["panel", "method"] + [f"{step_label(a)} env steps" for a in data.at] + [
        "gate open fraction", "closed-run length (steps)", "if independent (1 / open)",
        "gate probability std", "gate KL (nats, Σ units)"]
    if data.holding_gap is not None:
        header += [name for name, _ in HOLDING_COLUMNS]
        header += [f"units closed across {data.holding_gap} steps", "if independent"]
    rows = [header] + [[panel.title, method] + value_cells(data, panel.task, method)
                       + gate_cells(data, panel.task, method)
                       for panel in data.panels for method in panel.methods]
    text = markdown_table(rows)
    text += (f"\n\nA value is the evaluation nearest to the step, at most one evaluation "
             f"interval ({step_label(data.spacing)} env steps) away: mean ± std over seeds "
             "(n seeds). Gate columns: the mean over seeds of each seed's last `gates/open` "
             "and `gates/closed_run_mean` in `metrics.jsonl` (— for a method that logs no "
             "gates, or none yet; (n=k) where only k of its seeds logged the key); the mean "
             "closed run of gates that would open independently at every step with that "
             "probability, 1 / open (a little less in the training window, which cuts runs at "
             "its edges); the last `gates/prob_post_std`, the spread of the gate probability "
             "over units, steps and sequences (near 0: the gates respond to nothing); and the "
             "last `gates/kl`, the gates' KL to Bernoulli(kappa) summed over units, which the "
             "sparsity loss holds at its free nats (`wm.gate_free`).")
    if data.holding_gap is not None:
        text += (" Holding columns, each the mean over seeds of its last logged value: the "
                 "closed runs' 90th percentile and longest (`gates/closed_run_p90`, "
                 "`gates/closed_run_max`) beside those of independent gates with the same "
                 "open rate (the geometric null: `gates/null_run_p90`; `gates/null_run_max`, "
                 "the median longest of as many runs; both capped at the training window); "
                 "GateL0RD's rates of steps with any unit open and of units opened at least "
                 "once in a sequence; and the fraction of units that stayed closed for "
                 f"{data.holding_gap} steps or more (`{holding_keys(data.holding_gap)[0]}`), "
                 "beside the chance that independent gates with the same open rate do so "
                 f"within the training window (`{holding_keys(data.holding_gap)[1]}`).")
    verdicts = []
    if data.at:
        last = data.at[-1]
        verdicts = [verdict(data, panel, pair) for panel in data.panels for pair in panel.compare]
        verdicts += [memory_rule_line(rule, partial(stat_at, data, at=last), last)
                     for rule in data.rules]
    if verdicts:
        text += "\n\n" + "\n".join(f"- {line}" for line in verdicts)
    return text
