"""What the figures and tables share: colours, step labels, the missing-runs note, saving,
Markdown tables and number formatting."""

from __future__ import annotations

import math
import os
import textwrap
from pathlib import Path

import matplotlib
from matplotlib.figure import Figure

from experiments.report.runs import run_name
from experiments.spec import Run

matplotlib.use("Agg")  # figures are files; no display

FIGURE_FORMATS = ("png", "pdf")
# Fixed colours, so a method looks the same in every figure; others cycle through tab10.
COLOURS = {"DreamerV1": "tab:gray", "DreamerV2": "tab:blue", "VSG": "tab:red",
           "SVSG": "tab:green", "SSM": "tab:purple"}
EXTRA_COLOURS = ("tab:orange", "tab:brown", "tab:pink", "tab:olive", "tab:cyan")
FIGURE_NOTE_RUNS = 6  # runs named in a figure's "missing" note before it says "and N more"


def colour(method: str, methods: list[str]) -> str:
    if method in COLOURS:
        return COLOURS[method]
    others = [m for m in methods if m not in COLOURS]
    return EXTRA_COLOURS[others.index(method) % len(EXTRA_COLOURS)] if method in others \
        else "black"


def step_label(step: float) -> str:
    """1_000_000 -> "1M", 2_500_000 -> "2.5M", 50_000 -> "50k"."""
    for scale, suffix in ((1e6, "M"), (1e3, "k")):
        if abs(step) >= scale:
            return f"{step / scale:g}{suffix}"
    return f"{step:g}"


def missing_note(runs: list[Run], limit: int = FIGURE_NOTE_RUNS, width: int = 0,
                 with_task: bool = True) -> str:
    """``"missing: bbs_basic/VSG s1, ..."`` for a figure (empty when nothing is missing),
    wrapped to lines of ``width`` characters if ``width``."""
    if not runs:
        return ""
    names = [run_name(run) if with_task else f"{run.method} s{run.seed}" for run in runs[:limit]]
    more = f" and {len(runs) - limit} more (see report.md)" if len(runs) > limit else ""
    note = "missing: " + ", ".join(names) + more
    return textwrap.fill(note, width) if width else note


def write_missing_note(ax, runs: list[Run], width: int = 45) -> None:
    """The red ``missing: ...`` note of a panel's missing runs in its top left corner."""
    note = missing_note(runs, 4, width, False)
    if note:
        ax.text(0.02, 0.98, note, transform=ax.transAxes, va="top", fontsize=6,
                color="firebrick")


def save_figure(figure: Figure, stem: Path) -> list[Path]:
    """``stem``.png and ``stem``.pdf."""
    stem.parent.mkdir(parents=True, exist_ok=True)
    paths = []
    for suffix in FIGURE_FORMATS:
        path = stem.with_suffix(f".{suffix}")
        metadata = {"CreationDate": None} if suffix == "pdf" else {"Software": None}
        figure.savefig(path, dpi=120, metadata=metadata)
        paths.append(path)
    return paths


def panel_grid(count: int, max_columns: int = 4) -> tuple[int, int]:
    """(rows, columns) of a grid of ``count`` panels."""
    columns = min(max_columns, max(count, 1))
    return -(-max(count, 1) // columns), columns


def hide_unused(axes, used: int, rows: int, columns: int) -> None:
    """Hide the panels of a ``rows`` x ``columns`` grid after the first ``used``."""
    for index in range(used, rows * columns):
        axes[index // columns][index % columns].set_visible(False)


def markdown_table(rows: list[list[str]]) -> str:
    header, *body = rows
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in body]
    return "\n".join(lines)


def fmt(value: float | None, digits: int = 2, nan: str = "—") -> str:
    """``value`` with ``digits`` decimals; ``nan`` for None or NaN, ``±∞`` for infinities."""
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return nan
    if math.isinf(value):
        return "∞" if value > 0 else "−∞"
    return f"{value:.{digits}f}"


def relative(path: Path, start: Path) -> str:
    """``path`` relative to ``start``, as a Markdown link target."""
    return Path(os.path.relpath(path.resolve(), start.resolve())).as_posix()
