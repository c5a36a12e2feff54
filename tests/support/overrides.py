"""Overrides of a test's base config with some of its keys replaced (a key may be given once)."""

from __future__ import annotations


def replaced(base: list[str], *overrides: str) -> list[str]:
    """``base`` without the keys that ``overrides`` give, then ``overrides``."""
    given = {item.partition("=")[0] for item in overrides}
    return [item for item in base if item.partition("=")[0] not in given] + list(overrides)
