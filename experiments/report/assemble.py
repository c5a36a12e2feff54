"""The report: every ``[[figures]]`` entry of an experiment drawn into the output directory,
and ``report.md`` linking them."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from experiments.report.bars import bars_data, bars_markdown, draw_bars
from experiments.report.context import Context
from experiments.report.curves import curves_data, curves_text, draw_curves
from experiments.report.discovery import (
    discovery_data,
    discovery_latex,
    discovery_markdown,
    discovery_text,
)
from experiments.report.grid import draw_grid, grid_data, grid_markdown
from experiments.report.memory_len import draw_memory_len, memory_len_data, memory_len_markdown
from experiments.report.open_loop import draw_open_loop, open_loop_data, open_loop_markdown
from experiments.report.panels import draw_panels, panels_data, panels_markdown
from experiments.report.reference import REFERENCE_DIR
from experiments.report.rollouts import rollouts_data, rollouts_markdown
from experiments.report.runs import run_name, warn
from experiments.report.style import relative, step_label
from experiments.report.summary import draw_summary, summary_data, summary_markdown
from experiments.report.versus import draw_versus, versus_data, versus_markdown
from experiments.spec import DEFAULT_ROOT, PAPER_DIR, Experiment, Run
from vsgjax.loop.rundir import CONFIG_FILE, SCORES_FILE


@dataclass
class Section:
    """One figure or table of the report: its data, the files drawn, its Markdown."""

    kind: str
    name: str
    data: object
    files: list[Path] = field(default_factory=list)
    markdown: str = ""


@dataclass
class Report:
    experiment: Experiment
    out: Path
    sections: list[Section]
    missing: list[Run]
    problems: list[str]
    markdown: Path


def build_report(experiment: Experiment, root: Path = DEFAULT_ROOT, out: Path | None = None,
                 reference_dir: Path = REFERENCE_DIR, spacing: float | None = None,
                 definitions: Path = PAPER_DIR) -> Report:
    """Every figure of ``experiment`` into ``out`` (default ``root/<name>/report``), and
    ``report.md`` linking them; ``definitions``: where the experiments a panel names are."""
    out = Path(out) if out is not None else Path(root) / experiment.name / "report"
    out.mkdir(parents=True, exist_ok=True)
    context = Context.create(experiment, root, reference_dir, spacing, definitions)
    names = [figure.get("kind", "?") for figure in experiment.figures]
    sections = []
    for index, figure in enumerate(experiment.figures):
        kind = figure.get("kind", "?")
        name = kind if names.count(kind) == 1 else f"{kind}{index}"
        sections.append(section(context, kind, name, figure, out))
    if experiment.kind == "train":
        missing = context.missing_runs()
    else:
        missing = list(dict.fromkeys(run for s in sections
                                     for run in getattr(s.data, "missing", [])))
    report = Report(experiment, out, sections, missing, context.records.problems,
                    out / "report.md")
    report.markdown.write_text(report_markdown(report, context, Path(root)))
    return report


def section(context: Context, kind: str, name: str, figure: dict, out: Path) -> Section:
    """The section of one ``[[figures]]`` entry, its files written to ``out/<name>.*``."""
    stem = out / name
    if kind == "curves":
        data = curves_data(context)
        return Section(kind, name, data, draw_curves(data, stem), curves_text(data))
    if kind == "bars":
        data = bars_data(context, figure.get("at", ()))
        return Section(kind, name, data, draw_bars(data, stem), bars_markdown(data))
    if kind == "grid":
        data = grid_data(context, figure.get("at", ()))
        return Section(kind, name, data, draw_grid(data, stem), grid_markdown(data))
    if kind == "discovery_table":
        data = discovery_data(context)
        table = discovery_markdown(data)
        files = [stem.with_suffix(".md"), stem.with_suffix(".tex")]
        files[0].write_text(table + "\n")
        files[1].write_text(discovery_latex(data))
        return Section(kind, name, data, files, table + "\n\n" + discovery_text(data))
    if kind == "summary":
        data = summary_data(context)
        files = draw_summary(data, stem, context.experiment.methods)
        return Section(kind, name, data, files, summary_markdown(data))
    if kind == "versus":
        data = versus_data(context, figure.get("at", ()), figure.get("budget_minutes"))
        table = versus_markdown(data)
        files = draw_versus(data, stem) + [stem.with_suffix(".md")]
        files[-1].write_text(table + "\n")
        return Section(kind, name, data, files, table)
    if kind == "open_loop":
        data = open_loop_data(context, figure.get("at"))
        return Section(kind, name, data, draw_open_loop(data, stem), open_loop_markdown(data))
    if kind == "panels":
        data = panels_data(context, figure.get("panels", ()), figure.get("at", ()),
                           figure.get("memory_rule", ()), figure.get("holding_gap"))
        return Section(kind, name, data, draw_panels(data, stem), panels_markdown(data))
    if kind == "memory_len":
        data = memory_len_data(context, figure.get("published"), figure.get("baseline"))
        table = memory_len_markdown(data)
        files = draw_memory_len(data, stem) + [stem.with_suffix(".md")]
        files[-1].write_text(table + "\n")
        return Section(kind, name, data, files, table)
    if kind == "rollouts":
        data = rollouts_data(context)
        return Section(kind, name, data, [], rollouts_markdown(data, out))
    warn(f"figure kind {kind!r} is not known to experiments.report; skipped",
         context.records.problems)
    return Section(kind, name, None, [], f"Unknown figure kind {kind!r}: not drawn.")


def report_markdown(report: Report, context: Context, root: Path) -> str:
    """``report.md``: the settings, missing and incomplete runs, warnings, then the sections."""
    experiment = report.experiment
    runs = experiment.runs
    first = runs[0] if runs else None
    lines = [f"# {experiment.name}", "", experiment.description, ""]
    seeds = sorted({run.seed for run in runs})
    settings = (f"{len(runs)} (tasks: {len(experiment.tasks)}, methods: "
                f"{len(experiment.methods)}, seeds: {len(seeds)}), size `{first.size}`, "
                f"train.steps {first.steps}" if first else "none")
    lines += [f"- runs: {settings}; root `{root}`"]
    if experiment.kind == "evaluate":
        lines.append(f"- evaluates the trained runs of experiment `{experiment.source}` "
                     f"({experiment.episodes or 'the default number of'} episodes each)")
    elif experiment.kind == "rollouts":
        lines.append(f"- draws from the trained runs of experiment `{experiment.source}`")
    if experiment.reference:
        files = ", ".join(f"`experiments/reference_scores/{name}`"
                          for name in experiment.reference)
        lines.append(f"- reference: {files} (see `experiments/reference_scores/PROVENANCE.md`)")
    else:
        lines.append("- reference: none (no paper data in `experiments/reference_scores/`)")
    if context.reference is not None:
        lines.append(f"- grid: {step_label(context.spacing)} env steps")
    lines.append("")
    lines += ["## Missing runs", ""]
    if report.missing:
        lines.append(f"{len(report.missing)} of {len(runs)} runs have no results:")
        lines.append("")
        for run in report.missing:
            differs = context.records.differs(run) if experiment.kind == "train" else ""
            if differs:
                lines.append(f"- {run_name(run)}: `{run.logdir(root) / CONFIG_FILE}` is "
                             f"another run's (config differs: {differs}); not counted")
                continue
            where = (run.logdir(root) / SCORES_FILE if experiment.kind == "train"
                     else experiment.job_dir(run, root))
            lines.append(f"- {run_name(run)}: `{where}`")
    else:
        lines.append("None: every run has results.")
    lines.append("")
    incomplete = incomplete_runs(context) if experiment.kind == "train" else []
    if incomplete:
        lines += ["## Incomplete runs", "",
                  "Runs whose last evaluation is more than one grid bin before train.steps "
                  "(their seeds thin out the end of the curves):", ""]
        lines += [f"- {run_name(run)}: last evaluation at env step {last:g} of {run.steps}"
                  for run, last in incomplete]
        lines.append("")
    if report.problems:
        lines += ["## Warnings", ""] + [f"- {p}" for p in report.problems] + [""]
    for part in report.sections:
        lines += [f"## {part.name}", ""]
        for path in part.files:
            link = relative(path, report.out)
            if path.suffix == ".png":
                lines += [f"![{part.name}]({link})", ""]
        links = [f"[{p.suffix[1:].upper()}]({relative(p, report.out)})" for p in part.files]
        if links:
            lines += ["Files: " + ", ".join(links), ""]
        if part.markdown:
            lines += [part.markdown, ""]
    return "\n".join(lines)


def incomplete_runs(context: Context) -> list[tuple[Run, float]]:
    """Runs whose last evaluation is more than one grid bin short of their ``train.steps``."""
    found = []
    for run in context.experiment.runs:
        curve = context.records.scores(run)
        if curve is not None and float(curve.xs.max()) < run.steps - context.spacing:
            found.append((run, float(curve.xs.max())))
    return found
