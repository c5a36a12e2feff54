"""experiments.report on synthetic run directories (no training): the data behind every
figure, the paper's curves and numbers beside ours, missing runs, corrupt lines, files."""

import json
import math

import numpy as np
import pytest

from experiments import report
from experiments.report import REFERENCE_DIR, Context, ReportWarning
from experiments.spec import load_experiment
from vsgjax.registry.agents import AGENTS

BBS_REFERENCE = json.loads((REFERENCE_DIR / "vsg_paper_bbs.json").read_text())
DISCOVERY_REFERENCE = json.loads((REFERENCE_DIR / "vsg_paper_discovery.json").read_text())


def write_scores(run, root, xs, ys):
    logdir = run.logdir(root)
    logdir.mkdir(parents=True, exist_ok=True)
    record = {"task": run.task, "method": run.method, "seed": str(run.seed),
              "xs": [float(x) for x in xs], "ys": [float(y) for y in ys]}
    (logdir / "scores.jsonl").write_text(json.dumps(record) + "\n")
    return logdir / "scores.jsonl"


def paper_curves(task, method):
    return [r for r in BBS_REFERENCE if r["task"] == task and r["method"] == method]


def paper_near(task, method, at, spacing=100_000):
    """The reference's mean and std over seeds of the evaluation nearest ``at`` (within one
    bin; ties to the earlier), computed straight from the file."""
    values = []
    for record in paper_curves(task, method):
        xs = np.array(record["xs"])
        index = int(np.argmin(np.abs(xs - at)))
        if abs(xs[index] - at) <= spacing:
            values.append(record["ys"][index])
    return float(np.mean(values)), float(np.std(values)), len(values)


def test_names_map_to_the_reference_files():
    assert report.paper_task("bbs_basic") == "bringbackshapes_sparse_distract0_size1.0"
    assert report.paper_task("bbs_medium_d2") == "bringbackshapes_sparse_distract2_size1.4"
    assert report.paper_task("bbs_large_d4") == "bringbackshapes_sparse_distract4_size1.6"
    assert report.paper_task("dmc_walker_walk") == "dmc_walker_walk"
    reference = report.load_reference("vsg_paper_bbs.json")
    assert reference.spacing == 100_000
    assert reference.paper_names[("bbs_basic", "VSG")] == (
        "bringbackshapes_sparse_distract0_size1.0", "VSGC")
    assert len(reference.seeds("bbs_medium_d4", "SVSG")) == 5
    assert report.load_reference("vsg_paper_dmc.json").spacing == 50_000


def test_the_paper_files_methods_are_registered_display_names():
    """Runs write their agent's display name (the registry's); the paper's curves use the same
    names, so the report pairs them."""
    displays = {entry.display for entry in AGENTS.values()}
    for name in ("vsg_paper_bbs.json", "vsg_paper_dmc.json"):
        assert {method for _, method in report.load_reference(name).curves} <= displays


def test_binning_rule():
    assert report.bin_of(0, 100_000) == 0
    assert report.bin_of(1, 100_000) == 100_000
    assert report.bin_of(100_000, 100_000) == 100_000
    assert report.bin_of(100_001, 100_000) == 200_000
    assert report.bin_of(1_005_000, 100_000) == 1_100_000
    curve = report.Curve(np.array([5_000, 55_000, 105_000]), np.array([1.0, 2.0, 3.0]))
    assert report.binned(curve, 100_000) == {100_000: 2.0, 200_000: 3.0}  # latest in a bin
    x, mean, std, n = report.seed_stats([{0: 1.0, 100: 2.0}, {0: 3.0}])
    assert list(x) == [0, 100] and list(mean) == [2.0, 2.0]
    assert list(std) == [1.0, 0.0] and list(n) == [2, 1]  # population std over seeds present


def test_curves_lines_labels_and_reference(tmp_path):
    experiment = load_experiment("bbs_basic", seeds=2, steps=300_000)
    for run in experiment.runs:
        offset = 1.0 if run.seed else 0.0
        write_scores(run, tmp_path, [5_000, 55_000, 105_000, 155_000, 300_000],
                     [offset + v for v in (1, 2, 3, 4, 5)])
    data = report.curves_data(Context.create(experiment, tmp_path))
    lines = data.lines["bbs_basic"]
    assert set(lines) == {"DreamerV2", "DreamerV2 (paper)", "VSG", "VSG (paper)", "SVSG",
                          "SVSG (paper)", "DrQ-v2"}  # the paper's BBS file has no DrQ-v2
    ours = lines["VSG"]
    assert ours.source == "ours" and ours.label == "VSG"
    assert list(ours.x) == [100_000, 200_000, 300_000]
    np.testing.assert_allclose(ours.mean, [2.5, 4.5, 5.5])  # seeds 0 and 1: 2/3, 4/5, 5/6
    np.testing.assert_allclose(ours.std, [0.5, 0.5, 0.5])
    assert list(ours.n) == [2, 2, 2]
    paper = lines["VSG (paper)"]
    assert paper.source == "paper"
    assert paper.paper_name == ("bringbackshapes_sparse_distract0_size1.0", "VSGC")
    assert list(paper.x) == [0, 100_000, 200_000, 300_000]  # cut at the runs' last grid point
    records = paper_curves("bringbackshapes_sparse_distract0_size1.0", "VSGC")
    np.testing.assert_allclose(paper.mean, np.mean([r["ys"][:4] for r in records], axis=0))
    np.testing.assert_allclose(paper.std, np.std([r["ys"][:4] for r in records], axis=0))
    assert ("bbs_basic", "VSG", "bringbackshapes_sparse_distract0_size1.0", "VSGC") in \
        data.reference_drawn
    assert len(data.reference_drawn) == 3 and data.missing == [] and data.spacing == 100_000


def test_methods_without_reference_have_no_paper_curve(tmp_path):
    experiment = load_experiment("ssm", seeds=1, steps=100_000)
    for run in experiment.runs:
        write_scores(run, tmp_path, [50_000, 100_000], [1, 2])
    data = report.curves_data(Context.create(experiment, tmp_path))
    lines = data.lines["dmc_cartpole_swingup"]
    assert set(lines) == {"SVSG", "SVSG (paper)", "SSM"}
    assert list(lines["SSM"].x) == [50_000, 100_000]  # the DMC reference's 50k grid
    assert {method for _, method, _, _ in data.reference_drawn} == {"SVSG"}


def test_missing_runs_are_listed(tmp_path):
    experiment = load_experiment("bbs_basic", seeds=2, steps=200_000)
    absent = [run for run in experiment.runs if run.method == "SVSG" and run.seed == 1][0]
    for run in experiment.runs:
        if run != absent:
            write_scores(run, tmp_path, [100_000, 200_000], [1, 2])
    context = Context.create(experiment, tmp_path)
    assert report.curves_data(context).missing == [absent]
    assert report.bars_data(context, [100_000]).missing == [absent]
    assert report.summary_data(context).missing == [absent]
    assert report.missing_note([absent]) == "missing: bbs_basic/SVSG s1"
    built = report.build_report(experiment, tmp_path, tmp_path / "out")
    assert built.missing == [absent]
    text = built.markdown.read_text()
    assert "1 of 8 runs have no results" in text
    assert f"bbs_basic/SVSG s1: `{absent.logdir(tmp_path) / 'scores.jsonl'}`" in text


def test_corrupt_lines_are_skipped_with_a_warning(tmp_path):
    experiment = load_experiment("bbs_basic", seeds=1, steps=200_000)
    run = experiment.runs[0]
    path = write_scores(run, tmp_path, [100_000, 200_000], [1, 2])
    path.write_text(path.read_text() + '{"task": "bbs_basic", "xs": [1, 2\n')  # torn write
    records = report.RunRecords(tmp_path)
    with pytest.warns(ReportWarning, match=r"scores\.jsonl:2: skipped a corrupt line"):
        curve = records.scores(run)
    assert list(curve.xs) == [100_000, 200_000] and list(curve.ys) == [1, 2]
    assert any(str(path) + ":2" in problem for problem in records.problems)

    lines = ['{"step": 10, "return": 1.0}', "not json", "[1, 2]", '{"step": 10, "return": 3.0}']
    episodes = tmp_path / "eval_episodes.jsonl"
    episodes.write_text("\n".join(lines) + "\n")
    with pytest.warns(ReportWarning) as caught:
        records = report.read_jsonl(episodes)
    assert [r["return"] for r in records] == [1.0, 3.0]
    messages = [str(w.message) for w in caught]
    assert any(f"{episodes}:2: skipped a corrupt line" in m for m in messages)
    assert any(f"{episodes}:3: skipped a line that is not a JSON object" in m for m in messages)


def test_scores_rebuilt_from_eval_episodes_when_scores_file_is_absent(tmp_path):
    run = load_experiment("bbs_basic", seeds=1, steps=200_000).runs[0]
    logdir = run.logdir(tmp_path)
    logdir.mkdir(parents=True)
    rows = [{"step": 100_000, "episode": 0, "return": 1.0},
            {"step": 100_000, "episode": 1, "return": 3.0},
            {"step": 200_000, "episode": 0, "return": 4.0}]
    (logdir / "eval_episodes.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    with pytest.warns(ReportWarning, match="rebuilt them from"):
        curve = report.RunRecords(tmp_path).scores(run)
    assert list(curve.xs) == [100_000, 200_000] and list(curve.ys) == [2.0, 4.0]


def test_bars_at_1m_and_2_5m(tmp_path):
    experiment = load_experiment("bbs_basic", seeds=2)
    assert experiment.figures[1] == {"kind": "bars", "at": [1_000_000, 2_500_000]}
    xs = np.arange(5_000, 2_500_001, 50_000)  # evaluations 5k after the grid, as after prefill
    for run in experiment.runs:
        ys = xs / 1e6 + run.seed  # the score at step x of seed s: x / 1M + s
        if run.method == "SVSG" and run.seed == 1:
            xs_short = xs[xs < 1_200_000]  # stopped early: nothing near 2.5M
            write_scores(run, tmp_path, xs_short, xs_short / 1e6 + 1)
        else:
            write_scores(run, tmp_path, xs, ys)
    data = report.bars_data(Context.create(experiment, tmp_path), [1_000_000, 2_500_000])
    assert data.at == [1_000_000, 2_500_000]
    vsg_1m = data.values[("bbs_basic", "VSG", 1_000_000)]["ours"]
    assert vsg_1m.n == 2  # nearest to 1M: the evaluation at 1,005,000
    assert vsg_1m.mean == pytest.approx(1.005 + 0.5) and vsg_1m.std == pytest.approx(0.5)
    vsg_end = data.values[("bbs_basic", "VSG", 2_500_000)]["ours"]
    assert vsg_end.mean == pytest.approx(2.455 + 0.5)  # 2,455,000: the last, 45k before
    for method, paper_method in (("VSG", "VSGC"), ("DreamerV2", "DreamerV2"), ("SVSG", "SVSG")):
        for step in (1_000_000, 2_500_000):
            paper = data.values[("bbs_basic", method, step)]["paper"]
            mean, std, n = paper_near("bringbackshapes_sparse_distract0_size1.0", paper_method,
                                      step)
            assert (paper.mean, paper.std, paper.n) == (pytest.approx(mean), pytest.approx(std),
                                                        n)
    svsg_end = data.values[("bbs_basic", "SVSG", 2_500_000)]["ours"]
    assert svsg_end.n == 1
    assert [(run.method, run.seed, step) for run, step in data.missing_at] == [
        ("SVSG", 1, 2_500_000)]


def test_grid_is_scale_by_distractors(tmp_path):
    experiment = load_experiment("bbs_grid", seeds=1)
    for run in experiment.runs:
        if run.task != "bbs_large_d4":  # one task has no runs at all
            write_scores(run, tmp_path, [1_000_000, 2_500_000],
                         [1.0, 2.0 + (run.method == "VSG")])
    data = report.grid_data(Context.create(experiment, tmp_path), [1_000_000, 2_500_000])
    assert data.scales == [1.0, 1.2, 1.4, 1.6] and data.distractors == [0, 1, 2, 4]
    assert data.tasks[(1.4, 2)] == "bbs_medium_d2" and data.tasks[(1.0, 0)] == "bbs_basic"
    assert data.methods == ["DreamerV2", "VSG", "SVSG"]
    for table in (data.ours, data.paper, data.ours_std, data.paper_std):
        assert set(table) == {(m, s) for m in data.methods for s in (1_000_000, 2_500_000)}
        assert all(v.shape == (4, 4) for v in table.values())
    ours = data.ours[("VSG", 2_500_000)]
    assert ours[0, 0] == 3.0 and ours[2, 2] == 3.0 and math.isnan(ours[3, 3])
    assert data.ours[("SVSG", 1_000_000)][1, 3] == 1.0
    mean, _, _ = paper_near("bringbackshapes_sparse_distract2_size1.4", "VSGC", 2_500_000)
    assert data.paper[("VSG", 2_500_000)][2, 2] == pytest.approx(mean)
    assert np.isfinite(data.paper[("VSG", 2_500_000)][3, 3])  # the paper's cell is still there
    assert {run.task for run in data.missing} == {"bbs_large_d4"}
    paths = report.draw_grid(data, tmp_path / "grid")
    assert [p.name for p in paths] == ["grid.png", "grid.pdf"]


def write_evaluation(experiment, run, root, rows):
    job = experiment.job_dir(run, root)
    job.mkdir(parents=True, exist_ok=True)
    (job / "evaluation.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    return job / "evaluation.jsonl"


def episode(first_visit, length, never, not_scored):
    return {"step": 2_500_000, "episode": 0, "return": 1.0, "length": length,
            "discovery/mean_first_visit": first_visit, "discovery/never_visited": never,
            "discovery/visited_not_scored": not_scored, "discovery/episode_length": length,
            "scored": 1}


def test_discovery_table_paper_column_and_units(tmp_path):
    experiment = load_experiment("bbs_discovery", seeds=2)
    assert experiment.kind == "evaluate" and experiment.episodes == 50
    absent = list(experiment.runs[-2:])  # both seeds of bbs_medium_d2 / SVSG
    for run in experiment.runs:
        if run in absent:
            continue
        write_evaluation(experiment, run, tmp_path, [
            episode(100.0, 751, 20.0, 50.0), episode(None, 751, 100.0, None),
            episode(50.0, 300, 0.0, 0.0)])
    corrupt = write_evaluation(experiment, experiment.runs[0], tmp_path, [
        episode(100.0, 751, 20.0, 50.0), episode(None, 751, 100.0, None),
        episode(50.0, 300, 0.0, 0.0)])
    corrupt.write_text(corrupt.read_text() + "{broken\n")
    # one source run says its action repeat is 2 (its config.json), the others use the config's 4
    other = experiment.runs[1]
    other.logdir(tmp_path).mkdir(parents=True)
    (other.logdir(tmp_path) / "config.json").write_text(
        json.dumps({"env": {"action_repeat": 2, "time_limit": 3000}}))
    with pytest.warns(ReportWarning, match=r"evaluation\.jsonl:4"):
        data = report.discovery_data(Context.create(experiment, tmp_path))
    assert data.columns == DISCOVERY_REFERENCE["columns"]
    expected = {(r["task"], r["method"]): r["values"] for r in DISCOVERY_REFERENCE["rows"]}
    assert {(row.task, row.method): row.paper for row in data.rows} == expected
    first = data.rows[0]
    assert (first.task, first.method, first.episodes, first.seeds) == (
        "bbs_basic", "DreamerV2", 6, 2)
    # first visit: agent steps x repeat (seed 0: 4, seed 1: 2), the None episodes left out
    assert first.ours[0] == pytest.approx(np.mean([400, 200, 200, 100]))
    # episode length: x repeat, capped at the 3000-step time limit
    assert first.ours[1] == pytest.approx(np.mean([3000, 3000, 1200, 1502, 1502, 600]))
    assert first.ours[2] == pytest.approx(40.0) and first.ours[3] == pytest.approx(25.0)
    assert data.missing == absent
    assert data.short[0] == (experiment.runs[0], 3)  # 3 of the experiment's 50 episodes
    markdown, latex = report.discovery_markdown(data), report.discovery_latex(data)
    for values in expected.values():
        for value in values:
            assert f"{value:.2f}" in markdown and f"{value:.2f}" in latex
    last = markdown.splitlines()[-1]
    assert last.startswith("| bbs_medium_d2 | SVSG |") and "missing" in last
    assert r"\begin{tabular}" in latex and r"bbs\_medium\_d2" in latex


def test_summary_difference_in_paper_std_units(tmp_path):
    reference_dir = tmp_path / "reference"
    reference_dir.mkdir()
    # the paper: three seeds at 100k -> 10, 20, 30: mean 20, std sqrt(200/3)
    records = [{"task": "dmc_cartpole_swingup", "method": "SVSG", "seed": str(s),
                "xs": [0, 50_000, 100_000], "ys": [0, 5, y]} for s, y in enumerate((10, 20, 30))]
    (reference_dir / "vsg_paper_dmc.json").write_text(json.dumps(records))
    experiment = load_experiment("ssm", seeds=3, steps=100_000)
    for run in experiment.runs:
        if run.task != "dmc_cartpole_swingup":
            continue
        ys = {0: [1, 36], 1: [2, 40], 2: [3]}[run.seed]
        write_scores(run, tmp_path, [50_000, 100_000][:len(ys)], ys)
    context = Context.create(experiment, tmp_path, reference_dir)
    rows = {(r.task, r.method): r for r in report.summary_data(context).rows}
    svsg = rows[("dmc_cartpole_swingup", "SVSG")]
    assert svsg.step == 50_000  # seed 2 stopped at 50k: the last step all seeds reached
    assert svsg.ours.mean == pytest.approx(2.0) and svsg.paper.mean == pytest.approx(5.0)
    assert svsg.paper.std == 0.0 and svsg.difference == -math.inf

    for run in experiment.runs:  # seed 2 reaches 100k too
        if run.task == "dmc_cartpole_swingup" and run.seed == 2:
            write_scores(run, tmp_path, [50_000, 100_000], [3, 38])
    context = Context.create(experiment, tmp_path, reference_dir)
    data = report.summary_data(context)
    rows = {(r.task, r.method): r for r in data.rows}
    svsg = rows[("dmc_cartpole_swingup", "SVSG")]
    assert svsg.step == 100_000
    assert (svsg.ours.mean, svsg.ours.n) == (pytest.approx(38.0), 3)
    assert (svsg.paper.mean, svsg.paper.std) == (pytest.approx(20.0),
                                                 pytest.approx(math.sqrt(200 / 3)))
    assert svsg.difference == pytest.approx(18 / math.sqrt(200 / 3))  # = 2.20 paper stds
    assert rows[("dmc_cartpole_swingup", "SSM")].paper is None  # no reference for SSM
    assert math.isnan(rows[("dmc_cartpole_swingup", "SSM")].difference)
    missing_task = rows[("dmc_cheetah_run", "SVSG")]
    assert missing_task.step is None and missing_task.ours.n == 0
    assert {run.task for run in data.missing} == {"dmc_cheetah_run", "dmc_reacher_easy",
                                                  "dmc_walker_walk"}
    assert "2.20" in report.summary_markdown(data)
    assert report.std_units(3.0, 1.0, 0.5) == 4.0 and report.std_units(1.0, 1.0, 0.0) == 0.0


def test_rollouts_images_listed(tmp_path):
    experiment = load_experiment("rollouts", seeds=1)
    run = experiment.runs[1]
    job = experiment.job_dir(run, tmp_path)
    (job / "gates").mkdir(parents=True)
    (job / "rollout.png").write_bytes(b"\x89PNG")
    (job / "gates" / "heatmap.pdf").write_bytes(b"%PDF")
    (job / "notes.txt").write_text("not an image")
    built = report.build_report(experiment, tmp_path, tmp_path / "out")
    data = built.sections[0].data
    assert data.images == {run: [job / "gates" / "heatmap.pdf", job / "rollout.png"]}
    assert data.missing == [experiment.runs[0], experiment.runs[2]]
    text = built.markdown.read_text()
    assert "![rollout.png](../rollouts/bbs_basic/vsg/s0/rollout.png)" in text
    assert "[heatmap.pdf](../rollouts/bbs_basic/vsg/s0/gates/heatmap.pdf)" in text
    assert "2 of 3 runs have no results" in text


def test_cli_writes_png_pdf_and_report(tmp_path, capsys):
    experiment = load_experiment("bbs_basic", seeds=1, steps=4_000)
    write_scores(experiment.runs[0], tmp_path, [1_000, 2_000, 4_000], [0, 1, 2])
    write_scores(experiment.runs[1], tmp_path, [1_000, 2_000], [0, 1])  # stopped at 2000
    out = tmp_path / "out"
    assert report.main(["bbs_basic", "--root", str(tmp_path), "--out", str(out), "--seeds", "1",
                        "--steps", "4000", "--bin", "1000"]) == 0
    assert "2 of 4 runs missing" in capsys.readouterr().out  # SVSG s0 and DrQ-v2 s0
    for name in ("curves", "bars"):
        assert (out / f"{name}.png").read_bytes().startswith(b"\x89PNG")
        assert (out / f"{name}.pdf").read_bytes().startswith(b"%PDF")
    text = (out / "report.md").read_text()
    for link in ("![curves](curves.png)", "[PDF](curves.pdf)", "![bars](bars.png)",
                 "[PDF](bars.pdf)", "bbs_basic/SVSG s0"):
        assert link in text
    assert "- bbs_basic/VSG s0: last evaluation at env step 2000 of 4000" in text
    assert report.main(["no_such_experiment", "--root", str(tmp_path)]) == 2
    default = report.build_report(experiment, tmp_path, spacing=1_000)
    assert default.out == tmp_path / "bbs_basic" / "report"
    assert (default.out / "summary.png").exists() is False  # bbs_basic has no summary figure


DV3_REFERENCE = json.loads((REFERENCE_DIR / "dreamerv3_dmc_proprio.json").read_text())


def test_versus_table_and_figure_against_dreamerv3(tmp_path):
    experiment = load_experiment("cpu_proprio", seeds=2)
    assert {run.size for run in experiment.runs} == {"cpu"}
    assert experiment.runs[0].steps == 100_000
    written = [run for run in experiment.runs
               if run.task == "mjx_cartpole_swingup" and run.method == "VSG"]
    for run in written:  # seed 0 scores 400 at 100k, seed 1 300: mean 350 > DreamerV3's 321.6
        logdir = run.logdir(tmp_path)
        logdir.mkdir(parents=True)
        xs = [4_000.0 * k for k in range(1, 26)]
        ys = [(400.0 if run.seed == 0 else 300.0) * x / 100_000 for x in xs]
        record = {"task": run.task, "method": run.method, "seed": str(run.seed), "xs": xs,
                  "ys": ys, "wall_s": [18.0 * x / 1000 for x in xs], "cpu_s": xs}
        (logdir / "scores.jsonl").write_text(json.dumps(record) + "\n")
    built = report.build_report(experiment, tmp_path)
    versus = next(s for s in built.sections if s.kind == "versus")
    assert {p.suffix for p in versus.files} == {".png", ".pdf", ".md"}
    rows = {tuple(line.split(" | ")[:2]): line for line in versus.markdown.splitlines()
            if line.startswith("| mjx_")}
    released = [r for r in DV3_REFERENCE if r["task"] == "dmc_cartpole_swingup"]
    at_100k = [r["ys"][r["xs"].index(100_000)] for r in released]
    mean, std = float(np.mean(at_100k)), float(np.std(at_100k))
    released_row = rows[("| mjx_cartpole_swingup", "dreamerv3 (released)")]
    assert f"{mean:.1f} ± {std:.1f} (n=5)" in released_row
    ours = rows[("| mjx_cartpole_swingup", "VSG")]
    assert "350.0 ± 50.0 (n=2)" in ours and "70.0 ± 10.0 (n=2)" in ours  # 100k and 20k
    assert "30.0, 30.0 |" in ours  # wall minutes per run at the last evaluation
    assert "missing" in rows[("| mjx_walker_walk", "VSG")]
    assert "missing" in rows[("| mjx_cheetah_run", "VSG-stoch32")]  # a variant's own row
    # a group of some tasks has those tasks' rows only, and counts those tasks alone
    assert ("| mjx_cartpole_swingup", "VSG-stoch32") not in rows
    assert ("| mjx_cartpole_swingup", "VSG-stoch32x8-starts256") not in rows
    assert "missing" in rows[("| mjx_cheetah_run", "VSG-stoch32x8-starts256")]
    assert "VSG-stoch32x8-starts256: 0 of 1 task;" in versus.markdown
    assert "VSG: 1 of 5 tasks; DreamerV2: 0 of 5 tasks" in versus.markdown
    assert len(built.missing) == len(experiment.runs) - 2
