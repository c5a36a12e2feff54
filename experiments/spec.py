"""The paper's experiments as data: ``experiments/paper/<name>.toml`` -> runs and figures.

An experiment lists ``[[groups]]`` of runs (every task x model x seed of a group is one run) and
the ``[[figures]]`` they feed, or evaluates / draws from another experiment's trained runs
(``source``). ``load_experiment`` applies the launcher's ``--size``, ``--seeds`` and ``--steps``.
Every run has one log directory, ``<root>/<experiment>/<task>/<model>[-<variant>]/s<seed>``.
The file format is in docs/experiments.md.
"""

from __future__ import annotations

import argparse
import sys
import tomllib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from vsgjax.config import MODELS, SIZES, ConfigError, make_config
from vsgjax.envs import TaskError, parse_task
from vsgjax.registry.agents import agent_entry

PAPER_DIR = Path(__file__).resolve().parent / "paper"
DEFAULT_ROOT = Path("runs")
EVALUATION_FILE = "evaluation.jsonl"  # an evaluate job's episodes, one JSON object per line
KINDS = ("train", "evaluate", "rollouts")
_TOP_KEYS = {"description", "reference", "size", "steps", "seeds", "groups", "figures", "source",
             "episodes", "kind", "seeds_per_process"}
_GROUP_KEYS = {"tasks", "models", "variant", "method", "overrides", "steps", "seeds"}


class ExperimentError(ValueError):
    """A bad experiment name or definition; the message names the value and what is valid."""


def add_selection_arguments(parser: argparse.ArgumentParser) -> None:
    """The options that pick an experiment's runs, shared by the launcher and the report:
    ``NAME --size --seeds --steps --definitions --root``."""
    parser.add_argument("name", help="an experiment of --definitions (e.g. bbs_basic)")
    parser.add_argument("--size", default=None,
                        help=f"{', '.join(SIZES)} (default: the experiment's size, else paper)")
    parser.add_argument("--seeds", type=int, default=None, help="seeds 0..N-1 of every run")
    parser.add_argument("--steps", type=int, default=None, help="train.steps of every run")
    parser.add_argument("--definitions", type=Path, default=PAPER_DIR,
                        help="the directory of experiment files (default: experiments/paper)")
    parser.add_argument("--root", type=Path, default=DEFAULT_ROOT,
                        help="the runs are in ROOT/<experiment>/... (default: runs)")


def experiment_names(paper_dir: Path = PAPER_DIR) -> list[str]:
    """Every experiment defined in ``paper_dir`` (by default ``experiments/paper/``)."""
    return sorted(path.stem for path in Path(paper_dir).glob("*.toml"))


@dataclass(frozen=True)
class Run:
    """One training run (task x model [x variant] x seed) of an experiment."""

    experiment: str  # the experiment whose directory holds the run
    task: str
    model: str
    seed: int
    size: str = "paper"
    steps: int = 0
    variant: str = ""
    method_label: str = ""
    overrides: tuple[str, ...] = ()

    @property
    def method(self) -> str:
        """The name in figures and tables (the reference scores' names for plain models)."""
        return self.method_label or agent_entry(self.model).display + (
            f"-{self.variant}" if self.variant else "")

    @property
    def method_dir(self) -> str:
        return self.model + (f"-{self.variant}" if self.variant else "")

    def logdir(self, root: Path = DEFAULT_ROOT) -> Path:
        return Path(root) / self.experiment / self.task / self.method_dir / f"s{self.seed}"

    @property
    def config_overrides(self) -> tuple[str, ...]:
        """Overrides passed to ``vsgjax.train``: the group's, then ``train.steps``."""
        return (*self.overrides, f"train.steps={self.steps}")

    def config(self):
        """The resolved :class:`vsgjax.config.Config` this run trains with."""
        return make_config(self.task, self.model, self.size,
                           [f"train.seed={self.seed}", *self.config_overrides])

    def train_command(self, root: Path = DEFAULT_ROOT, python: str = sys.executable,
                      seeds: Sequence[int] = ()) -> list[str]:
        """``python -m vsgjax.train ...`` for this run (resumes if its logdir has a checkpoint),
        or for ``seeds`` of its task, method and config trained in one process (each in its own
        ``s<seed>`` directory)."""
        seeds = tuple(seeds) or (self.seed,)
        method_dir = self.logdir(root).parent
        if len(seeds) == 1:
            chosen = ["--seed", str(seeds[0]), "--logdir", str(method_dir / f"s{seeds[0]}")]
        else:
            chosen = ["--seeds", ",".join(str(seed) for seed in seeds),
                      "--logdir", str(method_dir / "s{seed}")]
        return [python, "-m", "vsgjax.train", "--task", self.task, "--model", self.model,
                "--size", self.size, *chosen, "--no-progress", *self.config_overrides]


@dataclass(frozen=True)
class Experiment:
    """An experiment: its runs and the figures they feed (see docs/experiments.md)."""

    name: str
    description: str
    kind: str  # "train", "evaluate" (source's checkpoints) or "rollouts" (drawn from them)
    runs: tuple[Run, ...]
    figures: tuple[dict, ...] = ()
    reference: tuple[str, ...] = ()  # reference files (a TOML string or list of strings)
    source: str | None = None  # the experiment whose runs an evaluate/rollouts experiment uses
    episodes: int = 0  # evaluation episodes per run (kind "evaluate")
    seeds_per_process: int = 1  # seeds of one task and method the local launcher trains together

    def job_dir(self, run: Run, root: Path = DEFAULT_ROOT) -> Path:
        """Where this experiment's job for ``run`` writes: the run's own log directory for a
        training experiment; ``<root>/<name>/<task>/<method>/s<seed>`` for an evaluate or
        rollouts experiment (whose ``run`` lives in the source experiment's directory)."""
        if self.kind == "train":
            return run.logdir(root)
        return Path(root) / self.name / run.task / run.method_dir / f"s{run.seed}"

    @property
    def tasks(self) -> list[str]:
        return list(dict.fromkeys(run.task for run in self.runs))

    @property
    def methods(self) -> list[str]:
        return list(dict.fromkeys(run.method for run in self.runs))


def load_experiment(name: str, size: str | None = None, seeds: int | None = None,
                    steps: int | None = None, paper_dir: Path = PAPER_DIR) -> Experiment:
    """The experiment ``name`` (a file in ``paper_dir``) with the launcher's overrides applied.

    ``size``: every run's size instead of the file's ``size`` (default ``paper``); ``seeds``:
    use seeds 0..seeds-1 instead of the file's; ``steps``: every run's ``train.steps``. Raises
    :class:`ExperimentError` naming a bad value and the valid ones.
    """
    valid = experiment_names(paper_dir)
    if name not in valid:
        raise ExperimentError(f"unknown experiment {name!r}; valid: {', '.join(valid)}")
    if size is not None and size not in SIZES:
        raise ExperimentError(f"unknown size {size!r}; valid: {', '.join(SIZES)}")
    for what, value in (("seeds", seeds), ("steps", steps)):
        if value is not None and value < 1:
            raise ExperimentError(f"--{what} must be a positive integer, got {value}")
    path = Path(paper_dir) / f"{name}.toml"
    try:
        data = tomllib.loads(path.read_text())
    except tomllib.TOMLDecodeError as error:
        raise ExperimentError(f"{path}: {error}") from None
    _check_keys(path, "top level", data, _TOP_KEYS)
    if size is None:
        size = data.get("size", "paper")
        if size not in SIZES:
            raise ExperimentError(f"{path}: unknown size {size!r}; valid: {', '.join(SIZES)}")
    kind = data.get("kind", "evaluate" if "source" in data else "train")
    if kind not in KINDS:
        raise ExperimentError(f"{path}: unknown kind {kind!r}; valid: {', '.join(KINDS)}")
    source = data.get("source")
    if kind == "train":
        runs = _expand(name, path, data, size, seeds, steps)
    else:
        if source is None:
            raise ExperimentError(f"{path}: kind {kind!r} needs a source experiment")
        runs = _select(load_experiment(source, size, seeds, steps, paper_dir), path, data)
    per_process = data.get("seeds_per_process", 1)
    if not isinstance(per_process, int) or per_process < 1:
        raise ExperimentError(f"{path}: seeds_per_process must be a positive integer, got "
                              f"{per_process!r}")
    return Experiment(name, data.get("description", ""), kind, tuple(runs),
                      tuple(data.get("figures", ())), _references(path, data), source,
                      int(data.get("episodes", 0)), per_process)


def _references(path: Path, data: dict) -> tuple[str, ...]:
    """The experiment's reference files: ``reference = "a.json"`` or ``["a.json", "b.json"]``
    (their curves are drawn together; the first one's step grid is the report's)."""
    names = data.get("reference", ())
    names = (names,) if isinstance(names, str) else tuple(names)
    if not all(isinstance(name, str) and name for name in names):
        raise ExperimentError(f"{path}: reference must be a file name or a list of them, got "
                              f"{data.get('reference')!r}")
    return names


def _check_keys(path: Path, where: str, table: dict, valid: set[str]) -> None:
    unknown = sorted(set(table) - valid)
    if unknown:
        raise ExperimentError(f"{path}: unknown keys {unknown} in {where}; "
                              f"valid: {', '.join(sorted(valid))}")


def _groups(path: Path, data: dict) -> list[dict]:
    groups = data.get("groups", [])
    if not groups:
        raise ExperimentError(f"{path}: no [[groups]] of runs")
    for index, group in enumerate(groups):
        _check_keys(path, f"group {index}", group, _GROUP_KEYS)
        for model in group.get("models", []):
            if model not in MODELS:
                raise ExperimentError(f"{path}: group {index}: unknown model {model!r}; "
                                      f"valid: {', '.join(MODELS)}")
        for task in group.get("tasks", []):
            try:
                parse_task(task)
            except (TaskError, ConfigError) as error:
                raise ExperimentError(f"{path}: group {index}: {error}") from None
    return groups


def _expand(name: str, path: Path, data: dict, size: str, seeds: int | None,
            steps: int | None) -> list[Run]:
    """Every task x model x seed of every group, in file order (a group's ``seeds`` caps the
    experiment's: a control trained with fewer seeds)."""
    count = seeds if seeds is not None else int(data.get("seeds", 1))
    runs = []
    for index, group in enumerate(_groups(path, data)):
        if steps is not None:
            total = steps
        elif "steps" in group or "steps" in data:
            total = int(group.get("steps", data.get("steps")))
        else:
            raise ExperimentError(f"{path}: group {index} has no steps (and no top-level steps)")
        group_count = min(count, int(group["seeds"])) if "seeds" in group else count
        for task in group["tasks"]:
            for model in group["models"]:
                for seed in range(group_count):
                    runs.append(Run(name, task, model, seed, size, total,
                                    group.get("variant", ""), group.get("method", ""),
                                    tuple(group.get("overrides", ()))))
    return runs


def _select(source: Experiment, path: Path, data: dict) -> list[Run]:
    """The source experiment's runs whose task and method its groups name."""
    wanted = [(task, model, group.get("variant", ""))
              for group in _groups(path, data) for task in group["tasks"]
              for model in group["models"]]
    runs = [run for run in source.runs if (run.task, run.model, run.variant) in wanted]
    missing = sorted({f"{t}/{m}" for t, m, v in wanted}
                     - {f"{r.task}/{r.model}" for r in runs})
    if missing:
        raise ExperimentError(f"{path}: source experiment {source.name!r} has no runs of "
                              f"{', '.join(missing)}")
    return runs

