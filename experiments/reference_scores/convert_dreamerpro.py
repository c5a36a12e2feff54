"""Rebuild ``dreamerpro_dmc.json`` from DreamerPro's released learning curves.

Source: https://github.com/fdeng18/dreamer-pro at commit ``SOURCE_COMMIT``, files
``plots/standard_dmc/runs.json`` and ``plots/natural_background_dmc/runs.json`` (each a JSON list
of ``{task, method, seed, xs, ys}``, 6 tasks x 3 methods x 3 seeds, written by the repository's
``common/plot.py``); provenance, units and checksums in ``PROVENANCE.md`` beside this file.

    python experiments/reference_scores/convert_dreamerpro.py PATH [--output FILE] [--rev REV]

``PATH`` is a checkout of the repository (a work tree holding ``plots/``) or its git directory
(a bare clone, read with ``git show REV:plots/...``; ``--rev`` defaults to HEAD). Both files
are checked against the sha256 recorded here; a changed or missing file stops the conversion
(``--allow-changed`` converts it anyway and says so).

What the conversion does (nothing else):

* task ``dmc_<domain>_<task>`` (standard DMC) and ``nat_<domain>_<task>`` (DMC with natural
  video backgrounds) -> ``dmc_<domain>_<task>``, with DreamerPro's ``cup`` -> ``ball_in_cup`` (as
  its ``common/envs.py`` does); the background is carried by the method label instead;
* method -> ``METHODS`` (the natural-background methods get the variant ``-natural``, as this
  project labels a run of variant ``natural``: display name + ``-natural``);
* ``xs`` -> integers, unchanged in value: DreamerPro's logger multiplies its step counter (agent
  steps) by the action repeat (2), so its xs are already this project's env steps;
* ``ys`` -> rounded to 1 decimal (mean eval return of each 10,000-env-step bin);
* ``seed`` unchanged (the authors' string labels ``indir1_1``..``indir1_3``).
"""

from __future__ import annotations

import json
import math
import sys
from itertools import pairwise
from pathlib import Path

try:
    from experiments.reference_scores import conversion
except ModuleNotFoundError:  # run as a script: this file's folder is on sys.path
    import conversion

SOURCE_REPO = "https://github.com/fdeng18/dreamer-pro"
SOURCE_COMMIT = "809b41757e1b08322011d5bcfc6e9f577f82c138"
OUTPUT = Path(__file__).resolve().parent / "dreamerpro_dmc.json"
STANDARD = "plots/standard_dmc/runs.json"
NATURAL = "plots/natural_background_dmc/runs.json"

# sha256 of each source file at SOURCE_COMMIT.
SHA256 = {
    STANDARD: "42d1eff98dfa6e83b99f17fd0f17b6a9613612ecb68da1243d26e5e13aa7def0",
    NATURAL: "f7b98c5ffbf82263e8fb37dfb6619b8ef99b8213322cdd751a46902287448dff",
}
# (source file, the authors' method) -> our label, in the output's method order.
METHODS = {
    (STANDARD, "dreamer_pro_v2_freeze_10k_norm_off"): "DreamerPro",
    (STANDARD, "dreamerv2"): "DreamerV2 (DreamerPro repo)",
    (STANDARD, "tpc_batch_150"): "TPC",
    (NATURAL, "dreamer_pro_v2_freeze_10k"): "DreamerPro-natural",
    (NATURAL, "dreamerv2_32"): "DreamerV2-natural (DreamerPro repo)",
    (NATURAL, "tpc_batch_150"): "TPC-natural",
}
TASK_PREFIX = {STANDARD: "dmc_", NATURAL: "nat_"}  # the authors' suite prefix per file
DOMAIN_NAMES = {"cup": "ball_in_cup"}  # DreamerPro's domain name -> dm_control's
KEYS = {"task", "method", "seed", "xs", "ys"}

ConversionError = conversion.ConversionError  # a source missing, changed or in another layout
dumps = conversion.dumps  # the canonical form of the output file


def project_task(name: str) -> str:
    """DreamerPro's task name -> this project's: ``nat_cup_catch`` and ``dmc_cup_catch`` ->
    ``dmc_ball_in_cup_catch``; ``dmc_cartpole_swingup_sparse`` stays as it is."""
    suite, _, rest = name.partition("_")
    if suite not in ("dmc", "nat") or not rest:
        raise ConversionError(f"task {name!r} is neither dmc_<domain>_<task> nor nat_...")
    domain, _, task = rest.partition("_")
    return f"dmc_{DOMAIN_NAMES.get(domain, domain)}_{task}"


def read_sources(path: Path, rev: str = "HEAD") -> dict[str, bytes]:
    """``{file: bytes}`` of both runs.json files of a work tree or a git directory."""
    if all((path / name).is_file() for name in SHA256):
        return {name: (path / name).read_bytes() for name in SHA256}
    sources = {}
    for name in SHA256:
        with conversion.git_or_missing(path, f"{name} nor a git blob {rev}:{name}"):
            sources[name] = conversion.git(path, "show", f"{rev}:{name}")
    return sources


def check_sources(sources: dict[str, bytes], allow_changed: bool = False) -> list[str]:
    """The differences from the recorded sha256s; raise unless ``allow_changed``."""
    return conversion.check_sources(sources, SHA256, SOURCE_COMMIT, allow_changed)


def records_of(name: str, data: bytes) -> list[dict]:
    """The records of one runs.json in our task and method names."""
    out = []
    for record in json.loads(data.decode()):
        if set(record) != KEYS:
            raise ConversionError(f"{name}: keys {sorted(record)}, expected {sorted(KEYS)}")
        task, method, seed = record["task"], record["method"], record["seed"]
        where = f"{name}: {task} {method} seed {seed}"
        if (name, method) not in METHODS:
            raise ConversionError(f"{where}: unknown method")
        if not task.startswith(TASK_PREFIX[name]):
            raise ConversionError(f"{where}: task not {TASK_PREFIX[name]}...")
        if not isinstance(seed, str):
            raise ConversionError(f"{where}: seed is not a string")
        xs, ys = record["xs"], record["ys"]
        if not xs or len(xs) != len(ys):
            raise ConversionError(f"{where}: {len(xs)} xs, {len(ys)} ys")
        if any(not math.isfinite(v) for v in (*xs, *ys)) or any(x != int(x) for x in xs):
            raise ConversionError(f"{where}: a non-finite value or a fractional x")
        xs = [int(x) for x in xs]
        if any(b <= a for a, b in pairwise(xs)):
            raise ConversionError(f"{where}: xs not increasing")
        out.append({"task": project_task(task), "method": METHODS[(name, method)],
                    "seed": seed, "xs": xs, "ys": [round(y, 1) for y in ys]})
    return out


def convert(sources: dict[str, bytes]) -> list[dict]:
    """Every record, sorted by task, then method (``METHODS`` order), then seed."""
    records = [r for name in SHA256 for r in records_of(name, sources[name])]
    order = {label: index for index, label in enumerate(METHODS.values())}
    keys = [(r["task"], r["method"], r["seed"]) for r in records]
    if len(set(keys)) != len(keys):
        raise ConversionError("a task x method x seed appears twice")
    return sorted(records, key=lambda r: (r["task"], order[r["method"]], r["seed"]))


def main(argv: list[str] | None = None) -> int:
    return conversion.main(
        argv, description=__doc__.split("\n\n")[0], output=OUTPUT,
        path={"help": "dreamer-pro checkout (work tree or git directory)"},
        read_sources=read_sources, check_sources=check_sources, convert=convert)


if __name__ == "__main__":
    sys.exit(main())
