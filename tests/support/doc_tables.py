"""Reading the config tables of the docs pages (``docs/presets.md``, ``docs/dreamerpro.md``) to
hold them against ``make_config``: a markdown table's rows, a cell's value, a dotted config key."""

from __future__ import annotations

from vsgjax.config.schema import DOTTED_FIELDS


def table_rows(text: str, header: str, after: str | None = None) -> list[list[str]]:
    """The stripped cells of each row of the markdown table whose header line is the first line
    of ``text`` that starts with ``header`` (the first after the line ``after``, if given): the
    lines after its separator line, up to the first that does not start with ``|``."""
    lines = text.splitlines()
    start = lines.index(after) if after is not None else 0
    at = next(i for i in range(start, len(lines)) if lines[i].startswith(header))
    rows = []
    for line in lines[at + 2:]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip("|").split("|")])
    return rows


def cell_value(text: str):
    """A table cell as the config holds it: ``True``/``False`` a bool, else an int, else a
    float, else the text."""
    if text in ("True", "False"):
        return text == "True"
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def config_value(config, key: str):
    """``config``'s value of a dotted key ``section.name`` (or of the top-level field the
    command line sets under it, ``model.precision``)."""
    if key in DOTTED_FIELDS:
        return getattr(config, DOTTED_FIELDS[key])
    section, name = key.split(".")
    return getattr(getattr(config, section), name)
