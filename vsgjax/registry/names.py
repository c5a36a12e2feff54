"""A "did you mean" for a misspelt name: the closest valid one, by difflib's ratio."""

from __future__ import annotations

import difflib
from collections.abc import Iterable


def closest(name: str, valid: Iterable[str]) -> str | None:
    """The valid name most like ``name``; None when none is close (difflib's similarity ratio
    below 0.6)."""
    close = difflib.get_close_matches(name, list(valid), n=1, cutoff=0.6)
    return close[0] if close else None


def did_you_mean(name: str, valid: Iterable[str], prefix: str = "", suffix: str = "") -> str:
    """`` (did you mean 'x'?)`` with the valid name closest to ``name`` between ``prefix`` and
    ``suffix``; "" when none is close. Compare only the part that varies (a task's name after
    its family's prefix), so a shared part does not make unrelated names look alike."""
    match = closest(name, valid)
    return f" (did you mean {prefix + match + suffix!r}?)" if match else ""
