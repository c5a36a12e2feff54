"""What the converters of released curves (``convert_*.py`` beside this file) share: the
canonical JSON form of the reference files, reading a source from a git directory, the check of
the source files against their recorded sha256, and the command line (``PATH [--output FILE]
[--rev REV] [--allow-changed]``: read, check, convert, write).

Standard library only, so that a converter also runs as a script
(``python experiments/reference_scores/convert_<name>.py``).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

Sources = dict[str, bytes]  # {source file: its bytes}


class ConversionError(ValueError):
    """A source file is missing, changed or not in the expected layout."""


def dumps(records: list[dict]) -> str:
    """Compact JSON, one record a line."""
    return "[\n" + ",\n".join(json.dumps(r, separators=(",", ":")) for r in records) + "\n]\n"


def git(git_dir: Path, *args: str) -> bytes:
    """The output of ``git --git-dir=GIT_DIR ARGS`` (``CalledProcessError`` if git fails)."""
    return subprocess.run(["git", f"--git-dir={git_dir}", *args], check=True,
                          capture_output=True).stdout


@contextmanager
def git_or_missing(path: Path, missing: str) -> Iterator[None]:
    """Turn a git failure inside into ``ConversionError("PATH has neither MISSING (git's
    message)")``."""
    try:
        yield
    except subprocess.CalledProcessError as error:
        raise ConversionError(f"{path} has neither {missing} "
                              f"({error.stderr.decode().strip()})") from error


def check_sources(sources: Sources, sha256: dict[str, str], commit: str,
                  allow_changed: bool = False, *, unrecorded: bool = False) -> list[str]:
    """The differences of ``sources`` from the recorded ``sha256`` of each file at ``commit``
    (with ``unrecorded``, also the files that have none); raise unless ``allow_changed``."""
    problems = [f"missing {name}" for name in sha256 if name not in sources]
    if unrecorded:
        problems += [f"not recorded: {name}" for name in sources if name not in sha256]
    digests = {name: hashlib.sha256(data).hexdigest() for name, data in sources.items()
               if name in sha256}
    problems += [f"changed: {name} (sha256 {digest})" for name, digest in digests.items()
                 if digest != sha256[name]]
    if problems and not allow_changed:
        raise ConversionError(f"the sources differ from commit {commit}: " + "; ".join(problems))
    return problems


def main(argv: list[str] | None, *, description: str, path: dict, output: Path,
         read_sources: Callable[[Path, str], Sources],
         check_sources: Callable[[Sources, bool], list[str]],
         convert: Callable[[Sources], list[dict]]) -> int:
    """A converter's command line: ``path`` holds the options of the ``path`` argument (its
    help, and a default where it may be left out); ``output`` is the default ``--output``."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("path", type=Path, **path)
    parser.add_argument("--output", type=Path, default=output)
    parser.add_argument("--rev", default="HEAD", help="git revision (git directories only)")
    parser.add_argument("--allow-changed", action="store_true",
                        help="convert files whose sha256 differs from the recorded one")
    args = parser.parse_args(argv)
    sources = read_sources(args.path, args.rev)
    for problem in check_sources(sources, args.allow_changed):
        print(f"warning: {problem}", file=sys.stderr)
    records = convert(sources)
    args.output.write_text(dumps(records))
    tasks = sorted({r["task"] for r in records})
    print(f"wrote {args.output}: {len(records)} records, {len(tasks)} tasks")
    return 0
