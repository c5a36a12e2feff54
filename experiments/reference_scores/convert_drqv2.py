"""Rebuild ``drqv2_dmc.json`` from DrQ-v2's released learning curves.

Source: https://github.com/facebookresearch/drqv2, folder ``curves/`` (one CSV per task, columns
``,agent,task,seed,frame,episode_reward,hour``), at commit ``SOURCE_COMMIT``; provenance, units
and checksums in ``PROVENANCE.md`` beside this file.

    python experiments/reference_scores/convert_drqv2.py PATH [--output FILE] [--rev REV]

``PATH`` is a checkout of the repository (a work tree holding ``curves/``) or its git directory
(a bare clone, read with ``git show REV:curves/<file>``; ``--rev`` defaults to HEAD). Every CSV
is checked against the sha256 recorded here; a changed or missing file stops the conversion
(``--allow-changed`` converts it anyway and says so).

What the conversion does (nothing else):

* task ``<domain>_<task>`` -> ``dmc_<domain>_<task>``, with DrQ-v2's ``cup`` -> ``ball_in_cup``
  (as its ``dmc.make`` does); ``reach_duplo`` is left out (a ``dm_control.manipulation`` task,
  not a suite task, so not a task of this project);
* ``frame`` -> ``xs`` unchanged: DrQ-v2's frame is agent steps x action repeat (2), which is
  this project's env steps (physics control steps);
* ``episode_reward`` -> ``ys`` rounded to 1 decimal (the mean return of DrQ-v2's 10 eval episodes);
* ``seed`` -> ``seed`` as a string; ``agent`` (always ``DrQ-v2``) -> ``method``; ``hour`` (wall
  clock) is dropped.
"""

from __future__ import annotations

import csv
import io
import sys
from itertools import pairwise
from pathlib import Path

try:
    from experiments.reference_scores import conversion
except ModuleNotFoundError:  # run as a script: this file's folder is on sys.path
    import conversion

SOURCE_REPO = "https://github.com/facebookresearch/drqv2"
SOURCE_COMMIT = "c0c650b76c6e5d22a7eb5f2edffd1440fe94f8ef"
METHOD = "DrQ-v2"
OUTPUT = Path(__file__).resolve().parent / "drqv2_dmc.json"
DOMAIN_NAMES = {"cup": "ball_in_cup"}  # DrQ-v2's domain name -> dm_control's
SKIPPED = {"reach_duplo": "dm_control.manipulation's reach_duplo_vision, not a suite task"}
COLUMNS = ["", "agent", "task", "seed", "frame", "episode_reward", "hour"]

# sha256 of curves/<file> at SOURCE_COMMIT.
SHA256 = {
    "dmc_acrobot_swingup.csv": "a7b52ffae88a0cf0e79edfabb7c1fd34eceb1d8c5263856f5c611614f900fa8d",
    "dmc_cartpole_balance.csv": "9a4b18e05ebcad1ae087a0cf3b7abce19d113ac1dd7b69fbb9bbb7f86c3edb0c",
    "dmc_cartpole_balance_sparse.csv":
        "f943ce8382029233615256fbcb3e6c26eba6f3e3a35725e7075c44c25352ab77",
    "dmc_cartpole_swingup.csv": "a6c6b1089d0c08ad610722f1be5c5745f7f8d019e8177a5822ba2912e2ce558b",
    "dmc_cartpole_swingup_sparse.csv":
        "9aef07198b238020d457e4b8583cdfde60c8a5d4f9cf0a8e9f0402c23f649032",
    "dmc_cheetah_run.csv": "b13ca12104568d53397dd359205336da77ee16cb68135c8035692c36c544b938",
    "dmc_cup_catch.csv": "25dec4b2603247796e9795ffcc6ee39df3d7817ec720da00809ad981740826b3",
    "dmc_finger_spin.csv": "31c7af0e4e72b5483d73708c9576ede5bf22366ff8567ec1aa2ab01e1210ad01",
    "dmc_finger_turn_easy.csv": "8b7d00a008156ca089285510d0a2ee05e0da480fa09594536be676488e3717ab",
    "dmc_finger_turn_hard.csv": "41f80676a21d69c43d098c4f6090f48b8787e1872d9e912b0bc04e5b4a89f451",
    "dmc_hopper_hop.csv": "1ab79a62d8ccc64a1b9cc9ad9bc9875da72eb597f9882617189705dd8fc0fc7d",
    "dmc_hopper_stand.csv": "b4bb11fb5b0745cf9237cc486d86f08aa901b6ee81ad16f6a4975dba01194453",
    "dmc_humanoid_run.csv": "b47face67ab890849237b650a68111da466f65ecd4219199c651725dc3c890ac",
    "dmc_humanoid_stand.csv": "b9fadab5842af6970f7419a382ddb290956613f801489ae771a1736f2c84ab62",
    "dmc_humanoid_walk.csv": "b0a8028a880631ea9533940c899d90e55ed7c3187e31c2d3d511025c4d750a40",
    "dmc_pendulum_swingup.csv": "e877a7f35c94b87998ca7f089319ab087e3014fb05b32584a758f3b2bcbde32a",
    "dmc_quadruped_run.csv": "4805772ce24a2dc2949be80560cc9b95e1db6cfc3ac6bc2033ee3d4d79fc09bb",
    "dmc_quadruped_walk.csv": "a123b11f1dc1acea5e9f1425246af52f3326ff27b6f7e83af7cbe88eea23e18a",
    "dmc_reach_duplo.csv": "13b01cede9ec905e9e2957dfd5c73e7735c8d358f4b61984ead6a56acfe4d91e",
    "dmc_reacher_easy.csv": "4047b5bc3d6ad182e0dbba4fffd85212caf3c1c90e757619e0a55de134fe9826",
    "dmc_reacher_hard.csv": "2c8213a74c507f7a2f166ce1b553e5d693891e43137ee87b3163545b88093ce0",
    "dmc_walker_run.csv": "7b82b8d9bde7ac05613140d372f3b70e23c2fec0ea96d076c46ac167d422be88",
    "dmc_walker_stand.csv": "737e73273437542629014a08966a8494376d3c6955f7e53bf22ddfb1eab4a561",
    "dmc_walker_walk.csv": "3e95c5a8bfc333dc9097f157709290b37595294dcebc53178f77061fbea71466",
}

ConversionError = conversion.ConversionError  # a source missing, changed or in another layout
dumps = conversion.dumps  # the canonical form of the output file


def project_task(drq_task: str) -> str:
    """DrQ-v2's task name -> this project's: ``cup_catch`` -> ``dmc_ball_in_cup_catch``."""
    domain, _, task = drq_task.partition("_")
    return f"dmc_{DOMAIN_NAMES.get(domain, domain)}_{task}"


def read_sources(path: Path, rev: str = "HEAD") -> dict[str, bytes]:
    """``{file name: bytes}`` of every ``curves/*.csv`` of a work tree or a git directory."""
    curves = path / "curves"
    if curves.is_dir():
        return {p.name: p.read_bytes() for p in sorted(curves.glob("*.csv"))}
    with conversion.git_or_missing(path, f"curves/ nor a git tree {rev}:curves/"):
        names = conversion.git(path, "ls-tree", "--name-only", rev, "curves/").decode().split()
    return {Path(n).name: conversion.git(path, "show", f"{rev}:{n}")
            for n in names if n.endswith(".csv")}


def check_sources(sources: dict[str, bytes], allow_changed: bool = False) -> list[str]:
    """The differences from the recorded sha256s (and the CSVs without one); raise unless
    ``allow_changed``."""
    return conversion.check_sources(sources, SHA256, SOURCE_COMMIT, allow_changed,
                                    unrecorded=True)


def records_of(name: str, data: bytes) -> list[dict]:
    """One ``{task, method, seed, xs, ys}`` record per seed of one CSV, seeds in order."""
    reader = csv.reader(io.StringIO(data.decode()))
    header = next(reader)
    if header != COLUMNS:
        raise ConversionError(f"{name}: columns {header}, expected {COLUMNS}")
    by_seed: dict[str, list[tuple[int, float]]] = {}
    task = None
    for row in reader:
        _, agent, row_task, seed, frame, reward, _ = row
        if agent != METHOD or (task is not None and row_task != task):
            raise ConversionError(f"{name}: unexpected row {row}")
        task = row_task
        by_seed.setdefault(seed, []).append((int(frame), float(reward)))
    records = []
    for seed in sorted(by_seed, key=int):
        points = sorted(by_seed[seed])
        xs = [x for x, _ in points]
        if any(b <= a for a, b in pairwise(xs)):
            raise ConversionError(f"{name} seed {seed}: repeated frames")
        records.append({"task": project_task(task), "method": METHOD, "seed": seed, "xs": xs,
                        "ys": [round(y, 1) for _, y in points]})
    return records


def convert(sources: dict[str, bytes]) -> list[dict]:
    """Every record, tasks in name order (``SKIPPED`` tasks left out)."""
    records = []
    for name, data in sources.items():
        drq_task = name.removeprefix("dmc_").removesuffix(".csv")
        if drq_task not in SKIPPED:
            records.extend(records_of(name, data))
    return sorted(records, key=lambda r: (r["task"], int(r["seed"])))


def main(argv: list[str] | None = None) -> int:
    return conversion.main(
        argv, description=__doc__.split("\n\n")[0], output=OUTPUT,
        path={"help": "drqv2 checkout (work tree or git directory)"},
        read_sources=read_sources, check_sources=check_sources, convert=convert)


if __name__ == "__main__":
    sys.exit(main())
