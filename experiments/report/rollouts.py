"""The ``rollouts`` section: the images the rollouts jobs wrote, linked from ``report.md``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from experiments.report.context import Context
from experiments.report.runs import run_name
from experiments.report.style import relative
from experiments.spec import Run

IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".gif", ".svg", ".pdf", ".mp4")
INLINE_SUFFIXES = (".png", ".jpg", ".jpeg", ".gif", ".svg")


@dataclass
class RolloutsData:
    images: dict[Run, list[Path]]  # run -> files its rollouts job wrote (sorted)
    missing: list[Run]  # rollouts jobs that wrote no image


def rollouts_data(context: Context) -> RolloutsData:
    images, missing = {}, []
    for run in context.experiment.runs:
        directory = context.experiment.job_dir(run, context.records.root)
        found = sorted(p for p in directory.rglob("*") if p.is_file()
                       and p.suffix.lower() in IMAGE_SUFFIXES) if directory.is_dir() else []
        if found:
            images[run] = found
        else:
            missing.append(run)
    return RolloutsData(images, missing)


def rollouts_markdown(data: RolloutsData, out: Path) -> str:
    parts = []
    for run, paths in data.images.items():
        parts.append(f"### {run_name(run)}\n")
        for path in paths:
            link = relative(path, out)
            if path.suffix.lower() in INLINE_SUFFIXES:
                parts.append(f"![{path.name}]({link})\n")
            else:
                parts.append(f"- [{path.name}]({link})\n")
    return "\n".join(parts) if parts else "No rollout images found."
