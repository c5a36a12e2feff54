"""The reports' rule for a method against a baseline: the difference of their means over seeds
set against the baseline's standard deviation over its seeds."""

from __future__ import annotations

ABOVE = "above the baseline beyond one standard deviation"
WITHIN = "within one std of the baseline"
BELOW = "below the baseline by more than one std"


def against_baseline(difference: float, baseline_std: float) -> str:
    """``ours − baseline`` above the baseline's std, within it (either side), or below it."""
    if difference > baseline_std:
        return ABOVE
    if difference >= -baseline_std:
        return WITHIN
    return BELOW
