"""The control rule of a partially observed variant: it tests memory only if a memoryless
control loses more to an agent with memory on the variant than on the fully observed task.

A ``[[figures.memory_rule]]`` table of a ``panels`` figure names one variant: ``{title, task,
agent, control, agent_full, control_full}``, four methods as the panels write them (e.g.
``DreamerV2-hidevel``, ``DrQ-v2-hidevel``, ``cpu_proprio/DreamerV2``, ``cpu_proprio/DrQ-v2``).
At the figure's last ``at`` step, with each method's mean over seeds,

    loss on the variant  = agent − control
    loss fully observed  = agent_full − control_full
    margin               = loss on the variant − loss fully observed

and the variant tests memory when the margin is positive. Its standard error, the square root
of the sum of each mean's squared standard error (std² / n, the four sets of seeds being
independent), is printed beside it: a margin within it is a weak pass or fail.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from experiments.report.binning import Stat
from experiments.report.runs import warn
from experiments.report.style import step_label

ROLES = ("agent", "control", "agent_full", "control_full")


@dataclass(frozen=True)
class MemoryRule:
    """One variant's rule: its task and the four methods it compares."""

    title: str
    task: str
    agent: str
    control: str
    agent_full: str
    control_full: str

    @property
    def methods(self) -> tuple[str, ...]:
        return tuple(getattr(self, role) for role in ROLES)


def read_memory_rules(entries, problems: list[str] | None = None) -> list[MemoryRule]:
    """The rules of a figure entry's ``memory_rule`` list; one without a task or any of the
    four methods is skipped with a warning naming what it lacks."""
    rules = []
    for index, entry in enumerate(entries):
        title = entry.get("title", entry.get("task"))
        lacking = [key for key in ("task", *ROLES) if not entry.get(key)]
        if lacking:
            warn(f"panels: memory_rule {index} ({title!r}) lacks {', '.join(lacking)} "
                 f"(it needs task, {', '.join(ROLES)}); skipped", problems)
            continue
        rules.append(MemoryRule(title, entry["task"], *(entry[role] for role in ROLES)))
    return rules


def memory_rule_line(rule: MemoryRule, stat: Callable[[str, str], Stat], at: float) -> str:
    """The rule's verdict at env step ``at``; ``stat(task, method)`` is a method's value there
    over seeds ("not enough runs" below 2 seeds for any of the four)."""
    stats = [stat(rule.task, method) for method in rule.methods]
    where = f"{rule.title}, at {step_label(at)} env steps"
    if min(s.n for s in stats) < 2:
        counts = ", ".join(f"{m} n={s.n}" for m, s in zip(rule.methods, stats, strict=True))
        return f"{where}: not enough runs for the control rule ({counts})."
    agent, control, agent_full, control_full = stats
    variant_loss = agent.mean - control.mean
    full_loss = agent_full.mean - control_full.mean
    margin = variant_loss - full_loss
    error = math.sqrt(sum(s.std ** 2 / s.n for s in stats))
    outcome = ("the control loses more on the variant: **it tests memory**" if margin > 0 else
               "the control loses no more on the variant: **it does not test memory**")
    strength = " (by less than the standard error)" if abs(margin) < error else ""
    return (f"{where}, the control rule: {rule.agent} − {rule.control} = {variant_loss:+.1f} "
            f"on the variant, {rule.agent_full} − {rule.control_full} = {full_loss:+.1f} fully "
            f"observed; margin {margin:+.1f} (standard error {error:.1f}): {outcome}{strength}.")
