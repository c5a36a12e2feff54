"""Checks of the ``gates/*`` lines both training loops log (vsgjax/loop/gate_logging.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import vsgjax
from vsgjax.agents.dreamer.gate_statistics import HOLDING_GAPS

SUMMARY_KEYS = {"gates/open", "gates/open_prior", "gates/prob_post", "gates/prob_post_std",
                "gates/prob_prior", "gates/kl", "gates/open_per_step_std",
                "gates/open_per_unit_std", "gates/never_open", "gates/always_open",
                "gates/closed_run_mean", "gates/closed_run_p90", "gates/closed_run_max",
                "gates/null_run_mean", "gates/null_run_p90", "gates/null_run_max",
                "gates/steps_any_open", "gates/units_ever_open", "gates/live_units",
                "gates/open_live"}
RUN_KEYS = {"gates/closed_run_mean", "gates/closed_run_p90", "gates/closed_run_max",
            "gates/null_run_mean", "gates/null_run_p90", "gates/null_run_max"}
HOLDING_KEYS = {f"gates/{name}_{gap}" for gap in HOLDING_GAPS  # those the window fits
                for name in ("holding", "null_holding", "live_holding", "live_null_holding")}
# where the batch shows episode starts (the live ones: and some unit opens)
CUE_KEYS = {f"gates/{live}{name}" for live in ("", "live_")
            for name in ("prob_step1", "prob_other_steps")}


def gate_lines(logdir: Path) -> list[dict]:
    records = map(json.loads, (logdir / "metrics.jsonl").read_text().splitlines())
    return [r for r in records if any(key.startswith("gates/") for key in r)]


def check_lines(lines: list[dict], final_step: int, first_step: int) -> None:
    """One line per log from the first training log to the end, every value a fraction
    (the KL and the run length excepted) and not constant."""
    steps = [line["step"] for line in lines]
    assert steps[0] == first_step and steps[-1] == final_step and steps == sorted(set(steps))
    for line in lines:
        assert set(line) - HOLDING_KEYS - CUE_KEYS == {"step", *SUMMARY_KEYS}
        assert len(CUE_KEYS & set(line)) in (0, 2, 4)
        assert {"gates/holding_5", "gates/null_holding_5"} <= set(line)
        fractions = [v for k, v in line.items() if k not in {"step", "gates/kl", *RUN_KEYS}]
        assert all(0.0 <= v <= 1.0 for v in fractions), line
        assert 0 < line["gates/open"] < 1 and line["gates/kl"] > 0
        assert all(line[key] >= 1 for key in RUN_KEYS)
    assert len({line["gates/kl"] for line in lines}) > 1  # the model changes between logs


def check_equals_loaded(logdir: Path, line: dict, batch: dict) -> None:
    run = vsgjax.load(logdir)
    assert run.step == line["step"]
    stats = vsgjax.gate_statistics(run.params, batch).summary()
    assert stats == pytest.approx({k: v for k, v in line.items() if k != "step"},
                                  rel=1e-6, abs=1e-7)
