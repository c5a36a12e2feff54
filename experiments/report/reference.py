"""The paper's numbers (``experiments/reference_scores/``) in our task and method names."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import bbs
from experiments.report.runs import Curve, scores_record
from vsgjax.registry.tasks import family_of

REFERENCE_DIR = Path(__file__).resolve().parents[1] / "reference_scores"
# Method names of a reference file that differ from ours (the paper's names -> ours).
PAPER_METHODS = {"vsg_paper_bbs.json": {"VSGC": "VSG"}}


def paper_task(task: str) -> str:
    """The reference files' name of our task: ``bbs_medium_d2`` ->
    ``bringbackshapes_sparse_distract2_size1.4``; ``mjx_walker_walk`` -> ``dmc_walker_walk``
    (a family whose tasks are another's: the same dm_control task); DMC and other names are
    the same."""
    family = family_of(task)
    if family.same_tasks_as:
        return f"{family.same_tasks_as}_{task.partition('_')[2]}"
    if task in bbs.VARIANTS:
        kwargs = bbs.VARIANTS[task]
        return (f"bringbackshapes_sparse_distract{kwargs['num_distractors']}"
                f"_size{kwargs['arena_scale']:.1f}")
    return task


def our_task(paper_name: str) -> str:
    """Our name of a reference file's task (the inverse of :func:`paper_task`)."""
    if paper_name.startswith("bringbackshapes_"):
        for task in bbs.VARIANTS:
            if paper_task(task) == paper_name:
                return task
    return paper_name


@dataclass
class Reference:
    """A reference file of learning curves, in our task and method names."""

    name: str
    curves: dict[tuple[str, str], list[Curve]]  # (our task, our method) -> one Curve per seed
    paper_names: dict[tuple[str, str], tuple[str, str]]  # ours -> the file's (task, method)
    spacing: float  # the step grid of the curves

    @classmethod
    def from_records(cls, name: str, records: list[dict]) -> Reference:
        """From the file's records ``{task, method, seed, xs, ys}``."""
        methods = PAPER_METHODS.get(name, {})
        ours_of_task: dict[str, str] = {}
        curves: dict[tuple[str, str], list[Curve]] = {}
        names: dict[tuple[str, str], tuple[str, str]] = {}
        diffs = []
        for record in records:
            task, method = record["task"], record["method"]
            if task not in ours_of_task:
                ours_of_task[task] = our_task(task)
            key = (ours_of_task[task], methods.get(method, method))
            curve = scores_record(record, str(record.get("seed", "")))
            if curve is None or not len(curve.xs):
                continue
            curves.setdefault(key, []).append(curve)
            names[key] = (task, method)
            diffs.extend(np.diff(curve.xs).tolist())
        spacing = float(np.median(diffs)) if diffs else 0.0
        return cls(name, curves, names, spacing)

    def seeds(self, task: str, method: str) -> list[Curve]:
        return self.curves.get((task, method), [])


def merge_references(references: list[Reference]) -> Reference:
    """Several reference files as one (their (task, method) curves side by side; the first
    file's step grid)."""
    if len(references) == 1:
        return references[0]
    curves, names = {}, {}
    for reference in references:
        clash = set(curves) & set(reference.curves)
        if clash:
            raise ValueError(f"reference {reference.name} repeats curves of another file: "
                             f"{sorted(clash)[:3]}")
        curves.update(reference.curves)
        names.update(reference.paper_names)
    return Reference(" + ".join(r.name for r in references), curves, names,
                     references[0].spacing)


def load_reference(name: str, directory: Path = REFERENCE_DIR) -> Reference:
    """The learning curves of ``directory/name`` (e.g. ``vsg_paper_bbs.json``)."""
    return Reference.from_records(name, json.loads((Path(directory) / name).read_text()))


def load_discovery_reference(name: str = "vsg_paper_discovery.json",
                             directory: Path = REFERENCE_DIR) -> dict:
    """Table 1: ``{"columns": [...], "values": {(task, method): [..]}, "source", "units"}``."""
    data = json.loads((Path(directory) / name).read_text())
    return {"columns": list(data["columns"]), "source": data.get("source", ""),
            "units": data.get("units", ""),
            "values": {(row["task"], row["method"]): [float(v) for v in row["values"]]
                       for row in data["rows"]}}
