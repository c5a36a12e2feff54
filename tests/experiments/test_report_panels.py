"""The report's ``panels`` figure and table from hand-written run directories
(experiments/report/panels.py): values at the ``at`` steps, the gate columns from
``metrics.jsonl``, the verdict of a panel's ``compare``, panels without runs."""

from __future__ import annotations

import dataclasses
import json

import pytest
from matplotlib.figure import Figure

from experiments import report
from experiments.report import Context, ReportWarning
from experiments.report.panels import draw_panel, panels_data
from experiments.spec import load_experiment

CARTPOLE = "mjx_cartpole_swingup"
STEPS = [20_000.0, 60_000.0, 100_000.0]
PANELS = [
    {"title": "hidden", "task": CARTPOLE, "methods": ["VSG-hidevel", "DreamerV2-hidevel"],
     "compare": ["VSG-hidevel", "DreamerV2-hidevel"]},
    {"title": "hidden, reversed", "task": CARTPOLE,
     "methods": ["VSG-hidevel", "DreamerV2-hidevel"],
     "compare": ["DreamerV2-hidevel", "VSG-hidevel"]},
    {"title": "noise", "task": CARTPOLE, "methods": ["VSG-noise16", "DreamerV2-noise16"],
     "compare": ["VSG-noise16", "DreamerV2-noise16"]},
    {"title": "empty", "task": "mjx_reacher_easy", "methods": ["DreamerV2-memoryless"]},
    {"title": "walker", "task": "mjx_walker_walk", "methods": ["SVSG", "DreamerV1"],
     "compare": ["SVSG", "DreamerV1"]},
]
# returns at 20k, 60k, 100k per seed
RETURNS = {
    "VSG-hidevel": [(10, 50, 300), (20, 60, 400), (30, 70, 500)],  # 100k: 400 ± 81.6
    "DreamerV2-hidevel": [(5, 40, 200), (5, 40, 250), (5, 40, 300)],  # 100k: 250 ± 40.8
    "VSG-noise16": [(1, 2, 325), (3, 4, 345)],  # seed 2 missing; 100k: 335 ± 10
    "DreamerV2-noise16": [(0, 0, 280), (0, 0, 320), (0, 0, 360)],  # 100k: 320 ± 32.7
}
# VSG-hidevel's gates per seed: (open, closed-run length, probability std, KL) of earlier
# lines, then the last (seed 0 logs no probability std: a run from before that key)
GATES = [((0.9, 100.0, None, 5.0), (0.2, 3.0, None, 0.09)),
         ((0.9, 100.0, 0.3, 5.0), (0.3, 4.0, 0.02, 0.1)),
         ((0.9, 100.0, 0.3, 5.0), (0.45, 6.0, 0.06, 0.14))]


def experiment_with_panels(panels=PANELS, at=(20_000, 100_000)):
    experiment = load_experiment("cpu_memory")
    return dataclasses.replace(experiment, figures=({"kind": "panels", "at": list(at),
                                                     "panels": panels},))


def runs_of(experiment, task, method):
    return sorted((r for r in experiment.runs if r.task == task and r.method == method),
                  key=lambda r: r.seed)


def write_scores(run, root, ys):
    logdir = run.logdir(root)
    logdir.mkdir(parents=True, exist_ok=True)
    (logdir / "scores.jsonl").write_text(json.dumps({"xs": STEPS, "ys": list(ys),
                                                     "wall_s": [1.0, 2.0, 3.0]}) + "\n")


def write_metrics(run, root, gates):
    """A train line, a gates line per (open, closed-run length, probability std, KL), then an
    eval line without gates: the last gates line is not the file's last line."""
    lines = [{"step": 2_000, "train/loss": 1.0}]
    lines += [{"step": 4_000 * k, "gates/open": open_, "gates/closed_run_mean": closed,
               "gates/kl": kl, "gates/never_open": 0.0}
              | ({} if spread is None else {"gates/prob_post_std": spread})
              for k, (open_, closed, spread, kl) in enumerate(gates, 1)]
    lines += [{"step": 100_000, "eval/return": 1.0}]
    path = run.logdir(root) / "metrics.jsonl"
    path.write_text("".join(json.dumps(line) + "\n" for line in lines))


def write_runs(experiment, root):
    for method, seeds in RETURNS.items():
        for run, ys in zip(runs_of(experiment, CARTPOLE, method), seeds, strict=False):
            write_scores(run, root, ys)
            write_metrics(run, root, [])
    for run, gates in zip(runs_of(experiment, CARTPOLE, "VSG-hidevel"), GATES, strict=True):
        write_metrics(run, root, gates)
    write_scores(runs_of(experiment, "mjx_walker_walk", "SVSG")[0], root, (1, 2, 3))
    for run in runs_of(experiment, "mjx_walker_walk", "DreamerV1"):
        write_scores(run, root, (0, 0, 0))


def table_rows(markdown):
    """(panel, method) -> the cells after those two, of every table row below the header."""
    lines = [line for line in markdown.splitlines() if line.startswith("| ")]
    rows = [[cell.strip() for cell in line.strip("|").split("|")] for line in lines[1:]]
    return {(cells[0], cells[1]): cells[2:] for cells in rows}


def verdict_of(markdown, title):
    (line,) = [line for line in markdown.splitlines() if line.startswith(f"- {title}, at")]
    return line


def test_panels_table_gates_verdicts_and_files(tmp_path):
    experiment = experiment_with_panels()
    write_runs(experiment, tmp_path)
    built = report.build_report(experiment, tmp_path, tmp_path / "out")
    (section,) = built.sections
    assert section.kind == "panels"
    assert [p.name for p in section.files] == ["panels.png", "panels.pdf"]
    assert all(p.exists() for p in section.files)
    assert section.files[0].read_bytes().startswith(b"\x89PNG")
    assert "![panels](panels.png)" in built.markdown.read_text()

    rows = table_rows(section.markdown)
    # at 20k and 100k, then open fraction, closed-run length, 1 / open, probability std, KL
    assert rows[("hidden", "VSG-hidevel")] == [  # (0.2+0.3+0.45)/3, 13/3, 3/0.95, 0.08/2, 0.33/3
        "20.0 ± 8.2 (n=3)", "400.0 ± 81.6 (n=3)", "0.32", "4.3", "3.2", "0.040 (n=2)", "0.110"]
    assert rows[("hidden", "DreamerV2-hidevel")] == [
        "5.0 ± 0.0 (n=3)", "250.0 ± 40.8 (n=3)", "—", "—", "—", "—", "—"]  # logs no gates
    assert rows[("noise", "VSG-noise16")] == ["2.0 ± 1.0 (n=2)", "335.0 ± 10.0 (n=2)", "—", "—",
                                              "—", "—", "—"]
    assert rows[("noise", "DreamerV2-noise16")][1] == "320.0 ± 32.7 (n=3)"
    assert rows[("empty", "DreamerV2-memoryless")] == ["no runs yet", "no runs yet", "—", "—",
                                                       "—", "—", "—"]
    assert rows[("walker", "SVSG")][:2] == ["1.0 ± 0.0 (n=1)", "3.0 ± 0.0 (n=1)"]

    # 400 - 250 = +150 > 40.8; 250 - 400 = -150 < -81.6; 335 - 320 = +15 within 32.7 (though
    # beyond ours' std 10: the baseline's std decides)
    assert verdict_of(section.markdown, "hidden").endswith(
        "VSG-hidevel − DreamerV2-hidevel = +150.0 (DreamerV2-hidevel's std 40.8): above the "
        "baseline beyond one standard deviation.")
    assert "= -150.0 (VSG-hidevel's std 81.6): below the baseline by more than one std." in \
        verdict_of(section.markdown, "hidden, reversed")
    assert verdict_of(section.markdown, "noise").endswith(
        "= +15.0 (DreamerV2-noise16's std 32.7): within one std of the baseline.")
    assert verdict_of(section.markdown, "walker").endswith(
        "not enough runs to compare SVSG (n=1) with DreamerV1 (n=3).")
    assert "- empty, at" not in section.markdown  # no compare, no verdict

    data = section.data
    noise = runs_of(experiment, CARTPOLE, "VSG-noise16")
    memoryless = runs_of(experiment, "mjx_reacher_easy", "DreamerV2-memoryless")
    assert noise[2] in data.missing and noise[0] not in data.missing
    assert all(run in data.missing for run in memoryless)
    assert not any(run.method == "DreamerV2-memoryless" and run.task == CARTPOLE
                   for run in data.missing)  # only the panels' task x methods are read
    assert data.gates[(CARTPOLE, "VSG-hidevel")]["gates/open"].n == 3


def test_a_method_keeps_its_colour_in_every_panel(tmp_path):
    """The panels "hidden" and "tuning" list VSG-hidevel second and first; its line has one
    colour, and no two methods of a panel share one."""
    panels = [{"title": "hidden", "task": CARTPOLE,
               "methods": ["DreamerV2-hidevel", "VSG-hidevel"]},
              {"title": "tuning", "task": CARTPOLE,
               "methods": ["VSG-hidevel", "VSG-noise16", "DreamerV2-noise16"]}]
    experiment = experiment_with_panels(panels)
    write_runs(experiment, tmp_path)
    data = panels_data(Context.create(experiment, tmp_path), panels, [100_000])
    axes = Figure().subplots(1, 2)
    colours = []
    for ax, panel in zip(axes, data.panels, strict=True):
        draw_panel(ax, panel, data)
        colours.append({line.get_label().split(" (")[0]: line.get_color() for line in ax.lines})
    assert colours[0]["VSG-hidevel"] == colours[1]["VSG-hidevel"]
    assert all(len(set(c.values())) == len(c) for c in colours)


def test_a_panel_draws_another_experiments_runs_and_gives_a_verdict_per_pair(tmp_path):
    """``cpu_proprio/DreamerV2`` is the fully observed baseline from that experiment's runs
    under the same root; ``compare`` as a list gives one verdict a pair; an unknown
    experiment is warned about and reads "no runs yet"."""
    panels = [{"title": "observed", "task": CARTPOLE,
               "methods": ["cpu_proprio/DreamerV2", "DreamerV2-hidevel", "VSG-hidevel",
                           "nowhere/DreamerV2"],
               "compare": [["VSG-hidevel", "DreamerV2-hidevel"],
                           ["DreamerV2-hidevel", "cpu_proprio/DreamerV2"]]}]
    experiment = experiment_with_panels(panels, at=(100_000,))
    write_runs(experiment, tmp_path)
    observed = runs_of(load_experiment("cpu_proprio"), CARTPOLE, "DreamerV2")
    for run, y in zip(observed, (600, 700, 800), strict=True):
        write_scores(run, tmp_path, (0, 0, y))
    assert observed[0].logdir(tmp_path).parts[-4] == "cpu_proprio"
    with pytest.warns(ReportWarning, match="unknown experiment 'nowhere'"):
        built = report.build_report(experiment, tmp_path, tmp_path / "out")
    markdown = built.sections[0].markdown
    rows = table_rows(markdown)
    assert rows[("observed", "cpu_proprio/DreamerV2")][0] == "700.0 ± 81.6 (n=3)"
    assert rows[("observed", "nowhere/DreamerV2")][0] == "no runs yet"
    verdicts = [line for line in markdown.splitlines() if line.startswith("- observed, at")]
    assert [line.split(": ", 1)[1] for line in verdicts] == [
        "VSG-hidevel − DreamerV2-hidevel = +150.0 (DreamerV2-hidevel's std 40.8): above the "
        "baseline beyond one standard deviation.",
        "DreamerV2-hidevel − cpu_proprio/DreamerV2 = -450.0 (cpu_proprio/DreamerV2's std "
        "81.6): below the baseline by more than one std."]


def test_a_report_without_any_runs_says_no_runs_yet(tmp_path):
    built = report.build_report(experiment_with_panels(), tmp_path, tmp_path / "out")
    rows = table_rows(built.sections[0].markdown)
    assert len(rows) == 9 and all(cells[:2] == ["no runs yet"] * 2 for cells in rows.values())
    assert verdict_of(built.sections[0].markdown, "hidden").endswith(
        "not enough runs to compare VSG-hidevel (n=0) with DreamerV2-hidevel (n=0).")
    assert all(path.exists() for path in built.sections[0].files)


def test_bad_panels_are_warned_about_not_fatal(tmp_path):
    panels = [{"title": "no task", "methods": ["SVSG"]},
              {"title": "typo", "task": CARTPOLE, "methods": ["SVSG", "VSG-hidevl"],
               "compare": ["SVSG", "DreamerV1"]}]
    experiment = experiment_with_panels(panels)
    context = Context.create(experiment, tmp_path)
    with pytest.warns(ReportWarning) as caught:
        data = panels_data(context, panels, [100_000])
    assert [panel.title for panel in data.panels] == ["typo"] and data.panels[0].compare == ()
    assert len(caught) == 3  # the panel without a task, the compare, the unknown method
    assert "no runs of VSG-hidevl on mjx_cartpole_swingup" in context.records.problems[-1]


def rule(title, agent, control, agent_full, control_full, task=CARTPOLE):
    return {"title": title, "task": task, "agent": agent, "control": control,
            "agent_full": agent_full, "control_full": control_full}


def test_the_memory_rule_passes_fails_flags_a_small_margin_and_waits_for_runs(tmp_path):
    """The loss of the control to the agent on the variant against the same loss fully
    observed: the margin, its standard error, the verdict; a rule lacking a method is warned
    about and skipped."""
    rules = [rule("passes", "DreamerV2-hidevel", "DrQ-v2-hidevel", "cpu_proprio/DreamerV2",
                  "cpu_proprio/DrQ-v2"),
             rule("weak", "DreamerV2-hidevel", "DrQ-v2-hidevel", "cpu_proprio/DrQ-v2",
                  "cpu_proprio/DreamerV2"),
             rule("fails", "DreamerV2-hidevel", "DrQ-v2-hidevel", "cpu_proprio/DreamerV2",
                  "cpu_proprio/VSG"),
             rule("waits", "SVSG", "DreamerV1", "cpu_proprio/DreamerV2", "cpu_proprio/DrQ-v2",
                  task="mjx_walker_walk"),
             {"title": "lacking", "task": CARTPOLE, "agent": "DreamerV2-hidevel"}]
    experiment = experiment_with_panels(PANELS[:1], at=(100_000,))
    experiment = dataclasses.replace(experiment, figures=(
        experiment.figures[0] | {"memory_rule": rules},))
    write_runs(experiment, tmp_path)  # DreamerV2-hidevel: 250 ± 40.8 (3)
    for run, y in zip(runs_of(experiment, CARTPOLE, "DrQ-v2-hidevel"), (100, 110, 120),
                      strict=True):
        write_scores(run, tmp_path, (0, 0, y))
    proprio = load_experiment("cpu_proprio")
    for method, ys in {"DreamerV2": (600, 700, 800), "DrQ-v2": (750, 800, 850),
                       "VSG": (90, 100, 110)}.items():
        for run, y in zip(runs_of(proprio, CARTPOLE, method), ys, strict=True):
            write_scores(run, tmp_path, (0, 0, y))
    with pytest.warns(ReportWarning, match="memory_rule 4 \\('lacking'\\) lacks control, "
                                           "agent_full, control_full"):
        built = report.build_report(experiment, tmp_path, tmp_path / "out")
    lines = {line.split(",", 1)[0][2:]: line for line in built.sections[0].markdown.splitlines()
             if line.startswith("- ") and "rule" in line}
    assert set(lines) == {"passes", "weak", "fails", "waits"}
    # standard error: sqrt((40.82² + 8.165² + 81.65² + 40.82²) / 3) = 57.9
    assert lines["passes"].endswith(
        "DreamerV2-hidevel − DrQ-v2-hidevel = +140.0 on the variant, cpu_proprio/DreamerV2 − "
        "cpu_proprio/DrQ-v2 = -100.0 fully observed; margin +240.0 (standard error 57.9): the "
        "control loses more on the variant: **it tests memory**.")
    assert lines["weak"].endswith("margin +40.0 (standard error 57.9): the control loses more "
                                  "on the variant: **it tests memory** (by less than the "
                                  "standard error).")
    assert "= +600.0 fully observed; margin -460.0" in lines["fails"]
    assert lines["fails"].endswith("**it does not test memory**.")
    assert lines["waits"].endswith("not enough runs for the control rule (SVSG n=1, DreamerV1 "
                                   "n=3, cpu_proprio/DreamerV2 n=0, cpu_proprio/DrQ-v2 n=0).")


def test_cpu_memory_defines_its_panels():
    (figure,) = [f for f in load_experiment("cpu_memory").figures if f["kind"] == "panels"]
    assert figure["at"] == [20_000, 60_000, 100_000]
    def controls(variant: str, versus: str) -> list:
        return [[f"DrQ-v2-{variant}", versus], [f"DreamerV2-{variant}-memoryless", versus]]

    observed = [["cpu_proprio/VSG", "cpu_proprio/DreamerV2"],
                ["cpu_proprio/DrQ-v2", "cpu_proprio/DreamerV2"]]
    assert [(p["task"], p.get("compare")) for p in figure["panels"]] == [
        (CARTPOLE, [["VSG-hidevel", "DreamerV2-hidevel"],
                    *controls("hidevel", "DreamerV2-hidevel")]),
        (CARTPOLE, ["VSG-hidevel-kappa05", "DreamerV2-hidevel"]),
        ("mjx_reacher_easy", [["VSG-target10", "DreamerV2-target10"],
                              *controls("target10", "DreamerV2-target10")]),
        (CARTPOLE, [["VSG-posonce", "DreamerV2-posonce"],
                    ["DrQ-v2-posonce", "DreamerV2-posonce"]]),
        (CARTPOLE, ["VSG-noise16", "DreamerV2-noise16"]),
        (CARTPOLE, [*observed, *[[f"DreamerV2-memoryless{kind}", "cpu_proprio/DreamerV2"]
                                 for kind in ("-starts", "")]]),
        ("mjx_reacher_easy", observed),
        (CARTPOLE, ["SVSG", "DreamerV1"]), ("mjx_walker_walk", ["SVSG", "DreamerV1"])]
    planned = {("cpu_memory", run.task, run.method) for run in load_experiment("cpu_memory").runs}
    planned |= {("cpu_proprio", run.task, run.method)
                for run in load_experiment("cpu_proprio").runs}
    rules = figure["memory_rule"]
    assert [(r["task"], r["agent"], r["control"]) for r in rules] == [
        (CARTPOLE, "DreamerV2-hidevel", "DrQ-v2-hidevel"),
        ("mjx_reacher_easy", "DreamerV2-target10", "DrQ-v2-target10"),
        (CARTPOLE, "DreamerV2-posonce", "DrQ-v2-posonce")]
    assert all((r["agent_full"], r["control_full"]) == ("cpu_proprio/DreamerV2",
                                                        "cpu_proprio/DrQ-v2") for r in rules)
    used = [(p["task"], m) for p in figure["panels"] for m in p["methods"]]
    used += [(r["task"], r[role]) for r in rules for role in ("agent", "control", "agent_full",
                                                               "control_full")]
    assert all((experiment, task, method) in planned for task, m in used
               for experiment, method in [(*m.split("/"),) if "/" in m else ("cpu_memory", m)])


def test_holding_columns_follow_the_gate_columns_when_a_gap_is_given(tmp_path):
    """``holding_gap`` adds the closed runs' p90 and max beside the geometric null's, GateL0RD's
    two other rates and the units closed across the gap; without it the table is as before."""
    experiment = experiment_with_panels(PANELS[:1], at=(100_000,))
    write_runs(experiment, tmp_path)
    holding = {"gates/closed_run_p90": 12.0, "gates/null_run_p90": 7.0,
               "gates/closed_run_max": 40.0, "gates/null_run_max": 9.0,
               "gates/steps_any_open": 0.5, "gates/units_ever_open": 0.75,
               "gates/holding_20": 0.25, "gates/null_holding_20": 0.0}
    for seed, run in enumerate(runs_of(experiment, CARTPOLE, "VSG-hidevel")):
        path = run.logdir(tmp_path) / "metrics.jsonl"
        line = {"step": 100_000, **{k: v + seed for k, v in holding.items()}}
        if seed == 2:  # a seed from before the holding keys
            line = {"step": 100_000}
        path.write_text(path.read_text() + json.dumps(line) + "\n")
    plain = table_rows(report.build_report(experiment, tmp_path,
                                           tmp_path / "a").sections[0].markdown)
    with_gap = dataclasses.replace(experiment, figures=(
        {**experiment.figures[0], "holding_gap": 20},))
    section = report.build_report(with_gap, tmp_path, tmp_path / "b").sections[0]
    rows = table_rows(section.markdown)
    assert rows[("hidden", "VSG-hidevel")] == plain[("hidden", "VSG-hidevel")] + [
        "12.5 (n=2)", "7.5 (n=2)", "40.5 (n=2)", "9.5 (n=2)", "1.00 (n=2)", "1.25 (n=2)",
        "0.75 (n=2)", "0.50 (n=2)"]
    assert rows[("hidden", "DreamerV2-hidevel")][-8:] == ["—"] * 8
    header = [line for line in section.markdown.splitlines() if line.startswith("| ")][0]
    assert header.rstrip(" |").endswith("units closed across 20 steps | if independent")
    assert "`gates/holding_20`" in section.markdown
    bad = dataclasses.replace(experiment, figures=({**experiment.figures[0],
                                                    "holding_gap": 0},))
    with pytest.warns(ReportWarning, match="holding_gap.*0"):
        rows = table_rows(report.build_report(bad, tmp_path, tmp_path / "c").sections[0]
                          .markdown)
    assert rows == plain
