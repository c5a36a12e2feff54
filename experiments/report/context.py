"""What every figure reads: the experiment, its runs' records, the reference, the grid."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from experiments.report.reference import (
    REFERENCE_DIR,
    Reference,
    load_reference,
    merge_references,
)
from experiments.report.runs import Curve, RunRecords
from experiments.spec import PAPER_DIR, Experiment, Run, load_experiment

FINE_GRID_BELOW = 3  # runs shorter than this many reference bins use their eval grid


@dataclass
class Context:
    """What every figure needs: the experiment, its runs' records, the reference, the grid."""

    experiment: Experiment
    records: RunRecords
    reference: Reference | None
    spacing: float
    reference_dir: Path = REFERENCE_DIR
    definitions: Path = PAPER_DIR  # where the experiment files are, the others' too
    others: dict[str, Experiment] = field(default_factory=dict)  # named by a panel's methods

    @classmethod
    def create(cls, experiment: Experiment, root: Path, reference_dir: Path = REFERENCE_DIR,
               spacing: float | None = None, definitions: Path = PAPER_DIR) -> Context:
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
        return cls(experiment, RunRecords(root), reference, float(spacing), Path(reference_dir),
                   Path(definitions))

    @property
    def steps(self) -> int:
        return max((run.steps for run in self.experiment.runs), default=0)

    def runs_of(self, task: str, method: str) -> list[Run]:
        """The experiment's runs of task x method; ``<experiment>/<method>`` names another
        experiment's (its file beside this one's, its runs under the same root, at its own
        size, seeds and steps), e.g. a fully observed baseline drawn beside a variant's runs.
        Raises :class:`~experiments.spec.ExperimentError` for an unknown experiment."""
        experiment = self.experiment
        if "/" in method:
            name, method = method.split("/", 1)
            if name not in self.others:
                self.others[name] = load_experiment(name, paper_dir=self.definitions)
            experiment = self.others[name]
        return [r for r in experiment.runs if r.task == task and r.method == method]

    def ours(self, task: str, method: str) -> tuple[list[Curve], list[Run]]:
        """Our seeds of task x method that have scores, and the runs that have none."""
        return self.scored(self.runs_of(task, method))

    def scored(self, runs: list[Run]) -> tuple[list[Curve], list[Run]]:
        """The curves of the ``runs`` that have scores, and the runs that have none."""
        curves, missing = [], []
        for run in runs:
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
