"""Every repository path and module named in the code, the config and the docs exists.

Scanned: README.md, BENCHMARKS.md, docs/*.md, pyproject.toml, the Makefile, and the ``.py``
files under vsgjax/, bbs/, experiments/ and tests/ (in Python only the comments, the strings
and the import statements: code that runs is checked by running it). Two kinds of name:

* a path written as text: a token that starts with a top-level folder (``vsgjax/``, ``bbs/``,
  ``experiments/``, ``tests/``, ``docs/``, ``.ci/``), such as ``vsgjax/loop/driver.py``,
  ``experiments/paper/`` or ``tests/loop/test_seeds`` (a module without its ``.py``); it must
  exist from the repository root, and a test id after it (``tests/test_docs.py::test_x``)
  must name a def or class of that file (a method of that class after a second ``::``);
* a dotted module name, ``vsgjax.x.y``, ``experiments.x.y`` or ``bbs.x.y``: the longest
  prefix that is a module or package must exist, and what follows it, or follows a ``:``
  (``vsgjax.registry.agents:MODELS``, the registries' form), may be one attribute that the
  module defines or imports at its top level (``vsgjax.agents.dreamer.api.train_step``; a
  class's own attributes after it are not checked);
* in Python, a Sphinx role with a name relative to its module (``:class:`MjxTask```,
  ``:meth:`observe```, ``:mod:`memory_check```): its first part must be a module of the
  same package, a name one of that package's modules defines or uses (a base class names
  the methods its subclasses implement), or an installed package (``:func:`jax.jit```).

Placeholders and generated names (a ``<``, ``{``, ``*``, ``$`` or ``...`` in the token, or a
run directory: ``runs/``, ``logdir/``) are skipped; anything else that names a path that is not
in the tree on purpose is in ``ALLOWED`` below, with its reason.
"""

from __future__ import annotations

import ast
import importlib.util
import io
import re
import tokenize
from functools import cache
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOP = ("vsgjax", "bbs", "experiments", "tests", "docs", r"\.ci")
MODULE_ROOTS = ("vsgjax", "experiments", "bbs")

TEXT_FILES = ["README.md", "BENCHMARKS.md", "pyproject.toml", "Makefile",
              *sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").glob("*.md"))]
PY_FILES = sorted(str(p.relative_to(ROOT)) for top in ("vsgjax", "bbs", "experiments", "tests")
                  for p in (ROOT / top).rglob("*.py") if "__pycache__" not in p.parts)

# A path: a top-level folder, then path characters, then any test ids ("::name"). Not preceded
# by a path character (so "../shared/docs/x.md" or "a/tests/b.py" is not one).
PATH = re.compile(r"(?<![\w./~$-])((?:" + "|".join(TOP) + r")/[\w./-]*(?:::\w+)*)")
# A dotted module name: vsgjax.x or experiments.x (not a file name's tail: "docs/experiments.md"),
# with an attribute after a colon if one follows ("vsgjax.registry.agents:MODELS").
DOTTED = re.compile(r"(?<![\w./-])((?:" + "|".join(MODULE_ROOTS)
                    + r")(?:\.[A-Za-z_]\w*)+(?::[A-Za-z_]\w*)?)")
ROLE = re.compile(r":(?:class|func|meth|attr|data|obj|exc|mod):`[~.]?([A-Za-z_]\w*)")
PLACEHOLDER = ("<", "{", "*", "$", "...", "runs/", "logdir/")
FILE_SUFFIXES = {"md", "py", "toml", "json", "jsonl", "txt", "png", "svg", "csv", "sh", "yaml",
                 "yml", "ipynb", "mcap", "npz", "pkl", "log", "html", "pdf", "gif", "mp4"}

# Names that are not in the tree on purpose, wherever they are written: name -> why. Keep it
# short; an entry that no longer matches anything fails the last test below.
ALLOWED: dict[str, str] = {
    # MCAP record and schema names in the episode files (vsgjax/data/replay/store.py), not modules
    "vsgjax.episode": "MCAP metadata record name",
    "vsgjax.action": "MCAP schema name",
    # docs/reports.md's how-to: the module a reader writes to add a report kind
    "experiments/report/mykind.py": "example of a file to create",
}
# This file quotes names that do not exist (its own checks' examples): it is not scanned.
SELF = str(Path(__file__).resolve().relative_to(ROOT))


def _dotted_candidates(text: str):
    for match in DOTTED.finditer(text):
        name = match.group(1).replace(":", ".")
        if name.rsplit(".", 1)[-1] in FILE_SUFFIXES:  # "experiments.md": a file, not a module
            continue
        yield match.start(1), name


def _path_candidates(text: str):
    for match in PATH.finditer(text):
        token = match.group(1).rstrip(".,;:")
        tail = text[match.end(1):match.end(1) + 1]
        if tail and tail in "<{*$":  # the token goes on as a placeholder: "runs/{seed}"
            continue
        yield match.start(1), token


def _skip(token: str) -> bool:
    return any(mark in token for mark in PLACEHOLDER)


def _python_texts(source: str):
    """(line, text) of the comments and strings of a Python file, and its imported modules."""
    for token in tokenize.generate_tokens(io.StringIO(source).readline):
        if token.type in (tokenize.COMMENT, tokenize.STRING) or (
                token.type == getattr(tokenize, "FSTRING_MIDDLE", -1)):
            first = token.start[0]
            for offset, line in enumerate(token.string.split("\n")):
                yield first + offset, line, False
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name, True
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            yield node.lineno, node.module, True
            for alias in node.names:
                if alias.name != "*":
                    yield node.lineno, f"{node.module}.{alias.name}", True


@cache
def _top_level_names(module_file: Path) -> frozenset[str] | None:
    """The names a module defines or imports at its top level; None when it has a module
    ``__getattr__`` (then its string constants count as names: lazily exported ones)."""
    tree = ast.parse(module_file.read_text())
    names, lazy = set(), False
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
            lazy |= node.name == "__getattr__"
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            for target in targets:
                names |= {n.id for n in ast.walk(target) if isinstance(n, ast.Name)}
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names |= {(a.asname or a.name).split(".")[0] for a in node.names}
        elif isinstance(node, (ast.If, ast.Try)):
            names |= {n.id for n in ast.walk(node) if isinstance(n, ast.Name)
                      and isinstance(n.ctx, ast.Store)}
            names |= {(a.asname or a.name).split(".")[0] for n in ast.walk(node)
                      if isinstance(n, (ast.Import, ast.ImportFrom)) for a in n.names}
    if lazy:
        names |= {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant)
                  and isinstance(n.value, str)}
    return frozenset(names)


def _module_file(parts: list[str]) -> Path | None:
    base = ROOT.joinpath(*parts)
    if (base / "__init__.py").exists():
        return base / "__init__.py"
    if base.with_suffix(".py").exists():
        return base.with_suffix(".py")
    if base.is_dir():  # a namespace package (tests/experiments has no __init__.py)
        return base
    return None


def path_exists(token: str) -> bool:
    """Whether a path (or the module it names without ``.py``) exists, and its test ids."""
    path, *test_ids = token.split("::")
    file = ROOT / path
    if not file.exists():
        file = file.with_name(file.name + ".py")
        if not file.is_file():
            return False
    scope = ast.parse(file.read_text()).body if test_ids else []
    for name in test_ids:
        node = next((n for n in scope if getattr(n, "name", None) == name), None)
        if node is None:
            return False
        scope = node.body if isinstance(node, ast.ClassDef) else []
    return True


@cache
def _every_name(module_file: Path) -> frozenset[str]:
    """Every name a module defines, imports, assigns or reads, at any depth (``self.x`` too)."""
    names = set()
    for node in ast.walk(ast.parse(module_file.read_text())):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, ast.Name):
            names.add(node.id)
        elif isinstance(node, ast.Attribute):
            names.add(node.attr)
        elif isinstance(node, ast.alias):
            names.add((node.asname or node.name).split(".")[0])
    return frozenset(names)


def role_exists(name: str, module_file: Path) -> bool:
    """Whether a role's first name is of the module's package or an installed package."""
    package = module_file.parent
    if (package / f"{name}.py").exists() or (package / name / "__init__.py").exists():
        return True
    if any(name in _every_name(module) for module in package.glob("*.py")):
        return True
    return name in MODULE_ROOTS or importlib.util.find_spec(name) is not None


def module_exists(name: str) -> bool:
    """Whether a dotted name is a module or package, or one's top-level attribute."""
    parts = name.split(".")
    for end in range(len(parts), 0, -1):
        found = _module_file(parts[:end])
        if found is None:
            continue
        rest = parts[end:]
        if not rest:
            return True
        if found.is_dir():
            return False
        return rest[0] in _top_level_names(found)
    return False


def missing_names() -> list[str]:
    """'file:line: name' for every path or module named that does not exist."""
    found = []

    def check(rel: str, line: int, text: str, import_only: bool = False):
        if import_only:
            names = [("module", text)] if text.split(".")[0] in MODULE_ROOTS else []
        else:
            names = [("path", t) for _, t in _path_candidates(text)]
            names += [("module", t) for _, t in _dotted_candidates(text)]
            if rel.endswith(".py"):
                names += [("role", m.group(1)) for m in ROLE.finditer(text)]
        for kind, name in names:
            if _skip(name) or name in ALLOWED:
                continue
            if kind == "path":
                exists = path_exists(name)
            elif kind == "role":
                exists = role_exists(name, ROOT / rel)
            else:
                exists = module_exists(name)
            if not exists:
                found.append(f"{rel}:{line}: {name}")

    for rel in TEXT_FILES:
        for number, line in enumerate((ROOT / rel).read_text().splitlines(), 1):
            check(rel, number, line)
    for rel in PY_FILES:
        if rel == SELF:
            continue
        for number, text, is_import in _python_texts((ROOT / rel).read_text()):
            check(rel, number, text, is_import)
    return sorted(set(found), key=lambda s: (s.split(":")[0], int(s.split(":")[1]), s))


def test_every_named_path_and_module_exists():
    missing = missing_names()
    assert not missing, f"{len(missing)} names of paths or modules that do not exist:\n" + \
        "\n".join(missing)


def test_the_scan_finds_paths_and_modules():
    """The patterns catch what they are for, so that a clean scan means something."""
    text = ("see `vsgjax/loop/driver.py`, docs/mjx.md, experiments/paper/ and "
            "vsgjax.agents.dreamer.api.train_step; not ../shared/docs/x.md, runs/{seed}/")
    assert [t for _, t in _path_candidates(text)] == [
        "vsgjax/loop/driver.py", "docs/mjx.md", "experiments/paper/"]
    assert [t for _, t in _dotted_candidates(text)] == ["vsgjax.agents.dreamer.api.train_step"]
    assert module_exists("vsgjax.config.make.make_config")  # a module's function
    assert module_exists("vsgjax.config.make_config")  # a package's import
    assert module_exists("vsgjax.load")  # a lazy export of the package
    assert module_exists("experiments.launch")
    assert not module_exists("vsgjax.model.api")
    assert not module_exists("vsgjax.config.presets.no_such_function")
    assert not (ROOT / "vsgjax/host.py").exists()


def test_the_scan_checks_test_ids_attributes_after_a_colon_and_relative_roles():
    text = ("tests/test_docs.py::test_readme_links_every_docs_page, tests/loop/test_seeds, "
            "vsgjax.registry.agents:MODELS and tests/test_mjx_host_loop")
    assert [t for _, t in _path_candidates(text)] == [
        "tests/test_docs.py::test_readme_links_every_docs_page", "tests/loop/test_seeds",
        "tests/test_mjx_host_loop"]
    assert [t for _, t in _dotted_candidates(text)] == ["vsgjax.registry.agents.MODELS"]
    assert path_exists("tests/test_docs.py::test_readme_links_every_docs_page")
    assert path_exists("tests/loop/test_seeds")  # a test module, named without its .py
    assert not path_exists("tests/test_mjx_host_loop")  # moved to tests/loop/
    assert not path_exists("tests/test_docs.py::test_gone")
    assert not module_exists("vsgjax.registry.agents.MODEL")
    assert [m.group(1) for m in ROLE.finditer(":class:`~MjxTask`, :meth:`observe()`")] == [
        "MjxTask", "observe"]
    mjx = ROOT / "vsgjax/envs/mjx/__init__.py"
    assert role_exists("MjxTask", mjx) and role_exists("vector_env", mjx)  # a name, a module
    assert role_exists("jax", mjx) and not role_exists("MjxHostEnv", mjx)


def test_every_allowed_name_is_still_named_and_still_missing():
    """An allowlist entry that no longer matches anything is removed, not kept."""
    texts = [(ROOT / rel).read_text() for rel in [*TEXT_FILES, *PY_FILES] if rel != SELF]
    for name in ALLOWED:
        assert any(name in text for text in texts), f"nothing names {name} any more"
        assert not ((ROOT / name).exists() or module_exists(name)), f"{name} exists now"


if __name__ == "__main__":
    print("\n".join(missing_names()))
