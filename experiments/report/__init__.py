"""An experiment's figures and tables beside the paper's (``python -m experiments.report``).

Reading runs (``runs``), the paper's numbers (``reference``), the grid (``binning``), what every
figure reads (``context``), one module per figure kind (``curves``, ``bars``, ``grid``,
``discovery``, ``summary``, ``versus``, ``open_loop``, ``panels``, ``rollouts``), the report
(``assemble``) and its command line (``cli``). Each figure has a data function and a drawing
function; the manual is docs/reports.md.
"""

from experiments.report.assemble import Report, Section, build_report
from experiments.report.bars import BarsData, bars_data, bars_markdown, draw_bars
from experiments.report.binning import Stat, bin_of, binned, seed_stats, value_near
from experiments.report.cli import main
from experiments.report.context import Context
from experiments.report.curves import CurvesData, Line, curves_data, draw_curves
from experiments.report.discovery import (
    DiscoveryData,
    discovery_data,
    discovery_latex,
    discovery_markdown,
)
from experiments.report.grid import GridData, draw_grid, grid_data, grid_markdown
from experiments.report.open_loop import (
    ErrorLine,
    OpenLoopData,
    draw_open_loop,
    open_loop_data,
    open_loop_markdown,
    read_open_loop,
)
from experiments.report.panels import PanelsData, draw_panels, panels_data, panels_markdown
from experiments.report.reference import (
    REFERENCE_DIR,
    Reference,
    load_discovery_reference,
    load_reference,
    paper_task,
)
from experiments.report.rollouts import RolloutsData, rollouts_data, rollouts_markdown
from experiments.report.runs import Curve, ReportWarning, RunRecords, read_jsonl
from experiments.report.style import colour, missing_note, save_figure, step_label
from experiments.report.summary import (
    SummaryData,
    draw_summary,
    std_units,
    summary_data,
    summary_markdown,
)

__all__ = [
    "REFERENCE_DIR", "BarsData", "Context", "Curve", "CurvesData", "DiscoveryData", "ErrorLine",
    "GridData", "Line", "OpenLoopData", "PanelsData", "Reference", "Report", "ReportWarning",
    "RolloutsData", "RunRecords", "Section", "Stat", "SummaryData", "bars_data", "bars_markdown",
    "bin_of", "binned", "build_report", "colour", "curves_data", "discovery_data",
    "discovery_latex", "discovery_markdown", "draw_bars", "draw_curves", "draw_grid",
    "draw_open_loop", "draw_panels", "draw_summary", "grid_data", "grid_markdown",
    "load_discovery_reference", "load_reference", "main", "missing_note", "open_loop_data",
    "open_loop_markdown", "panels_data", "panels_markdown", "paper_task", "read_jsonl",
    "read_open_loop", "rollouts_data", "rollouts_markdown", "save_figure", "seed_stats",
    "std_units", "step_label", "summary_data", "summary_markdown", "value_near",
]
