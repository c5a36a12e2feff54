"""What every figure reads: the experiment, its runs' records, the reference, the grid."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from experiments.report.reference import (
    REFERENCE_DIR,
    Reference,
    load_reference,
    merge_references,
)
from experiments.report.runs import Curve, RunRecords
from experiments.spec import Experiment, Run

FINE_GRID_BELOW = 3  # runs shorter than this many reference bins use their eval grid


@dataclass
class Context:
    """What every figure needs: the experiment, its runs' records, the reference, the grid."""

    experiment: Experiment
    records: RunRecords
    reference: Reference | None
    spacing: float
    reference_dir: Path = REFERENCE_DIR

    @classmethod
    def create(cls, experiment: Experiment, root: Path, reference_dir: Path = REFERENCE_DIR,
               spacing: float | None = None) -> Context:
        """The grid spacing is ``spacing``, else the reference's, else (no reference, or runs
        shorter than ``FINE_GRID_BELOW`` reference bins) the runs' ``train.eval_every``."""
        reference = None
        if experiment.reference and experiment.kind == "train":
            reference = merge_references([load_reference(name, reference_dir)
                                          for name in experiment.reference])
        steps = max((run.steps for run in experiment.runs), default=0)
        if spacing is None:
            if reference is not None and steps >= FINE_GRID_BELOW * reference.spacing > 0:
                spacing = reference.spacing
            elif experiment.runs:
                spacing = float(experiment.runs[0].config().train.eval_every)
            else:
                spacing = 1.0
        return cls(experiment, RunRecords(root), reference, float(spacing), Path(reference_dir))

    @property
    def steps(self) -> int:
        return max((run.steps for run in self.experiment.runs), default=0)

    def runs_of(self, task: str, method: str) -> list[Run]:
        return [r for r in self.experiment.runs if r.task == task and r.method == method]

    def ours(self, task: str, method: str) -> tuple[list[Curve], list[Run]]:
        """Our seeds of task x method that have scores, and the runs that have none."""
        curves, missing = [], []
        for run in self.runs_of(task, method):
            curve = self.records.scores(run)
            if curve is None:
                missing.append(run)
            else:
                curves.append(curve)
        return curves, missing

    def paper(self, task: str, method: str) -> list[Curve]:
        return self.reference.seeds(task, method) if self.reference is not None else []

    def missing_runs(self) -> list[Run]:
        return [run for run in self.experiment.runs if self.records.scores(run) is None]
