"""The two registries: every agent (``--model``) and every task family (``--task``'s prefix).

They are the only places that list model names and task families; every other module asks
them. Both are plain data at the bottom of the import graph (below ``config``): an entry names
the code that implements it as a ``"module:attribute"`` string, imported only when used
(:func:`resolve`), so registering an agent or a family adds no import arrow.
"""

from __future__ import annotations

import importlib


def resolve(reference: str):
    """The object a ``"package.module:attribute"`` reference names (imported on first use)."""
    module, _, attribute = reference.partition(":")
    return getattr(importlib.import_module(module), attribute)
