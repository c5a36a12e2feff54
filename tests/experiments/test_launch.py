"""Tests of ``python -m experiments.launch`` (and ``vsgjax.evaluate --output``) on the CPU.

The experiments are small TOML files written into a temporary ``--definitions`` directory:
``two`` (a 400-step and a 2800-step debug run), ``two_eval`` (evaluates them) and ``one`` (one
1000-step run). Launchers and jobs are subprocesses sharing one XLA compilation cache, so only
the first training run compiles.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from experiments import launch
from experiments.spec import EVALUATION_FILE, load_experiment
from tests.support.subprocess_env import subprocess_env
from vsgjax import evaluate
from vsgjax.config import make_config, to_dict

ROOT = Path(__file__).resolve().parents[2]
TIMEOUT = 600
OVERRIDES = '["env.time_limit=200", "train.ckpt_every=2"]'  # 51-step episodes, many checkpoints
SHORT, LONG = 400, 2800  # multiples of the 40-env-step chunks
ONE = 1000  # the single run the SLURM tests stop and requeue
DEFINITIONS = {
    "two": f"""
description = "launcher test: a short and a long debug run"
steps = {SHORT}
seeds = 1

[[groups]]
tasks = ["bbs_basic"]
models = ["vsg"]
overrides = {OVERRIDES}

[[groups]]
tasks = ["bbs_basic"]
models = ["vsg"]
variant = "long"
steps = {LONG}
overrides = {OVERRIDES}
""",
    "two_eval": """
description = "launcher test: evaluate the runs of two"
source = "two"
kind = "evaluate"
episodes = 2

[[groups]]
tasks = ["bbs_basic"]
models = ["vsg"]

[[groups]]
tasks = ["bbs_basic"]
models = ["vsg"]
variant = "long"
""",
    "one": f"""
description = "launcher test: one debug run"
steps = {ONE}

[[groups]]
tasks = ["bbs_basic"]
models = ["vsg"]
overrides = {OVERRIDES}
""",
}


@pytest.fixture(scope="module")
def definitions(tmp_path_factory) -> Path:
    directory = tmp_path_factory.mktemp("definitions")
    for name, text in DEFINITIONS.items():
        (directory / f"{name}.toml").write_text(text)
    return directory


@pytest.fixture(scope="module")
def child_env() -> dict:
    return subprocess_env()


def launch_args(name: str, definitions: Path, root: Path, *extra: str) -> list[str]:
    return [name, "--definitions", str(definitions), "--root", str(root), "--size", "debug",
            *extra]


def start_launcher(args: list[str], env: dict, out: Path) -> subprocess.Popen:
    with open(out, "w") as file:
        return subprocess.Popen([sys.executable, "-m", "experiments.launch", *args], cwd=ROOT,
                                env=env, stdout=file, stderr=subprocess.STDOUT, text=True)


def wait_for(predicate, process: subprocess.Popen, out: Path, timeout: float = TIMEOUT):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return
        if process.poll() is not None:
            raise AssertionError(f"launcher ended early ({process.returncode}):\n"
                                 + out.read_text()[-4000:])
        time.sleep(0.3)
    process.kill()
    raise AssertionError("timed out:\n" + out.read_text()[-4000:])


def snapshot(directory: Path) -> dict[str, int]:
    """Every file under ``directory`` with its modification time."""
    return {str(p.relative_to(directory)): p.stat().st_mtime_ns
            for p in sorted(directory.rglob("*")) if p.is_file()}


def headers(log: Path) -> int:
    return sum(line.startswith("=== ") for line in log.read_text().splitlines())


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory, definitions, child_env) -> dict:
    """Launch ``two`` with 2 local jobs, SIGTERM the launcher once the short run is done and the
    long one has a checkpoint, then relaunch it to the end."""
    root = tmp_path_factory.mktemp("runs")
    experiment = load_experiment("two", "debug", paper_dir=definitions)
    short, long = (launch.Job(i, experiment, run, root) for i, run in enumerate(experiment.runs))
    args = launch_args("two", definitions, root, "--backend", "local", "--jobs", "2",
                       "--interval", "2")
    first_out = root / "first.out"
    first = start_launcher(args, child_env, first_out)
    wait_for(lambda: f"done 0 {short.name}" in first_out.read_text()
             and launch.checkpoint_step(long.job_dir) is not None, first, first_out)
    interrupted_at = launch.checkpoint_step(long.job_dir)
    first.send_signal(signal.SIGTERM)
    first.wait(timeout=TIMEOUT)
    short_files = snapshot(short.job_dir)
    stopped_at = launch.checkpoint_step(long.job_dir)
    started = time.monotonic()
    second = subprocess.run([sys.executable, "-m", "experiments.launch", *args], cwd=ROOT,
                            env=child_env, capture_output=True, text=True, timeout=TIMEOUT)
    return dict(root=root, short=short, long=long, first_code=first.returncode,
                first_out=first_out.read_text(), interrupted_at=interrupted_at,
                stopped_at=stopped_at, short_files=short_files, second=second,
                second_s=time.monotonic() - started)


# --- the local backend: interrupt, skip, resume ------------------------------------------------


@pytest.mark.slow
def test_local_launch_interrupted_then_relaunched_skips_finished_and_resumes(two_runs):
    short, long, second = two_runs["short"], two_runs["long"], two_runs["second"]
    assert two_runs["first_code"] == 128 + signal.SIGTERM, two_runs["first_out"][-3000:]
    assert "SIGTERM: stopping" in two_runs["first_out"]
    stopped_at = two_runs["stopped_at"]
    assert two_runs["interrupted_at"] <= stopped_at < LONG  # it checkpointed when stopped
    first_log = long.log.read_text().split("\n=== ")[0]
    assert f"SIGTERM: saved a checkpoint at env step {stopped_at}" in first_log

    assert second.returncode == 0, second.stdout[-3000:] + second.stderr[-3000:]
    # the finished run was skipped: not relaunched, none of its files touched
    assert snapshot(short.job_dir) == two_runs["short_files"]
    assert headers(short.log) == 1
    assert re.search(rf"^0\s+{re.escape(short.name)}\s+done\s.*skipped", second.stdout, re.M)
    # the other resumed from its checkpoint and finished
    assert headers(long.log) == 2
    resumed = long.log.read_text().split("\n=== ")[1]
    assert f"resuming from ckpt-{stopped_at:012d}.ckpt: env step {stopped_at}" in resumed
    assert f"done: {LONG} env steps" in resumed
    assert launch.checkpoint_step(long.job_dir) == LONG
    scores = json.loads((long.job_dir / "scores.jsonl").read_text())
    assert scores["xs"][-1] == LONG and scores["method"] == "VSG"
    assert re.search(rf"^1\s+{re.escape(long.name)}\s+done\s+{LONG}/{LONG}", second.stdout,
                     re.M)
    assert second.stdout.rstrip().endswith("two: 2 jobs: 2 done")


@pytest.mark.slow
def test_the_report_draws_the_launched_runs(two_runs, definitions):
    """experiments.report on the runs the launcher trained: one curve per run, ending at its
    train.steps, nothing missing; the experiment has no reference, so no paper curve."""
    from experiments import report

    experiment = load_experiment("two", "debug", paper_dir=definitions)
    context = report.Context.create(experiment, two_runs["root"])
    data = report.curves_data(context)
    assert data.missing == [] and data.reference_drawn == []
    lines = data.lines["bbs_basic"]
    assert set(lines) == {"VSG", "VSG-long"}
    assert [line.source for line in lines.values()] == ["ours", "ours"]
    assert lines["VSG"].x[-1] >= SHORT and lines["VSG-long"].x[-1] >= LONG
    assert lines["VSG-long"].x[-1] < LONG + context.spacing
    written = report.draw_curves(data, two_runs["root"] / "curves")
    assert {path.suffix for path in written} == {".png", ".pdf"}


# --- the evaluate experiment and vsgjax.evaluate --output --------------------------------------


@pytest.mark.slow
def test_evaluate_experiment_writes_episode_files_and_is_then_skipped(two_runs, definitions,
                                                                      child_env, capsys):
    root = two_runs["root"]
    args = launch_args("two_eval", definitions, root, "--jobs", "2")
    result = subprocess.run([sys.executable, "-m", "experiments.launch", *args], cwd=ROOT,
                            env=child_env, capture_output=True, text=True, timeout=TIMEOUT)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    for run, step in ((two_runs["short"], SHORT), (two_runs["long"], LONG)):
        path = root / "two_eval" / run.run.task / run.run.method_dir / "s0" / EVALUATION_FILE
        records = [json.loads(line) for line in path.read_text().splitlines()]
        assert [r["episode"] for r in records] == [0, 1]
        assert all(r["step"] == step for r in records)
        assert {"return", "length", "discovery/mean_first_visit",
                "discovery/never_visited"} <= set(records[0])
        assert not list(path.parent.glob(".*.tmp"))  # written atomically
        command = f"-m vsgjax.evaluate {run.job_dir} --episodes 2 --output {path}"
        assert command in (path.parent / launch.LOG_FILE).read_text()
    assert launch.main(args) == 0  # relaunch: nothing to do
    out = capsys.readouterr().out
    assert out.count("skipped: finished before this launch") == 2


def test_evaluate_without_checkpoint_is_an_error_naming_the_run(tmp_path, capsys):
    config = make_config("bbs_basic", "vsg", "debug")
    (tmp_path / "config.json").write_text(json.dumps(to_dict(config)))
    output = tmp_path / "out" / EVALUATION_FILE
    assert evaluate.main([str(tmp_path), "--output", str(output)]) == 2
    err = capsys.readouterr().err
    assert str(tmp_path) in err and "no checkpoint" in err
    assert not output.exists()


def test_episode_records_write_nan_as_null(tmp_path):
    infos = [{"return": 1.5, "length": 10, "discovery/mean_first_visit": float("nan")}]
    path = evaluate.write_episodes(tmp_path / EVALUATION_FILE, infos, 1200)
    assert json.loads(path.read_text()) == {"step": 1200, "episode": 0, "return": 1.5,
                                            "length": 10, "discovery/mean_first_visit": None}


# --- the slurm backend through submitit's local executor ---------------------------------------


@pytest.mark.slow
def test_slurm_backend_via_submitit_local_requeues_on_preemption_and_finishes(
        tmp_path, definitions, child_env):
    """The array job is preempted (SIGUSR2 to submitit's worker, as SLURM's signal) once it has a
    checkpoint: it stops the trainer, requeues itself and the requeued job resumes."""
    pytest.importorskip("submitit")
    psutil = pytest.importorskip("psutil")
    experiment = load_experiment("one", "debug", paper_dir=definitions)
    job = launch.make_jobs(experiment, tmp_path)[0]
    args = launch_args("one", definitions, tmp_path, "--backend", "slurm", "--cluster", "local",
                       "--gpus-per-job", "0", "--time", "30", "--wait", "--interval", "1")
    out = tmp_path / "launcher.out"
    launcher = start_launcher(args, child_env, out)
    folder = tmp_path / "one" / launch.SUBMITIT_DIR
    wait_for(lambda: list(folder.glob("*_submitted.pkl"))
             and launch.checkpoint_step(job.job_dir) is not None, launcher, out)
    controller = int(next(folder.glob("*_submitted.pkl")).name.split("_")[0])
    (worker,) = psutil.Process(controller).children()
    worker.send_signal(signal.SIGUSR2)
    assert launcher.wait(timeout=TIMEOUT) == 0, out.read_text()[-3000:]
    log = job.log.read_text()
    assert headers(job.log) == 2, log[-3000:]
    stopped = int(re.search(r"SIGTERM: saved a checkpoint at env step (\d+)", log).group(1))
    assert f"resuming from ckpt-{stopped:012d}.ckpt" in log
    assert launch.checkpoint_step(job.job_dir) == ONE
    assert "1 jobs: 1 done" in out.read_text()


def test_slurm_without_submitit_names_the_extra(definitions, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(launch.slurm, "_Checkpointable", object)
    assert launch.main(launch_args("one", definitions, tmp_path, "--backend", "slurm")) == 2
    assert 'pip install -e ".[slurm]"' in capsys.readouterr().err
    monkeypatch.setitem(sys.modules, "submitit", None)  # import submitit -> ImportError
    experiment = load_experiment("one", "debug", paper_dir=definitions)
    with pytest.raises(launch.LaunchError, match=re.escape('pip install -e ".[slurm]"')):
        launch.submit_slurm(launch.make_jobs(experiment, tmp_path), experiment, tmp_path,
                            launch.parse_args(["one"]))


# --- the print backend -------------------------------------------------------------------------


def test_print_writes_commands_and_an_sbatch_array(definitions, tmp_path, capsys):
    code = launch.main(launch_args("two", definitions, tmp_path, "--backend", "print",
                                   "--jobs", "2", "--partition", "gpu", "--time", "120"))
    assert code == 0
    out = capsys.readouterr().out
    commands, sbatch = tmp_path / "two" / "commands.txt", tmp_path / "two" / "sbatch.sh"
    assert str(commands) in out and str(sbatch) in out
    lines = commands.read_text().splitlines()
    experiment = load_experiment("two", "debug", paper_dir=definitions)
    assert [shlex.split(line) for line in lines] == [
        job.command() for job in launch.make_jobs(experiment, tmp_path)]
    assert all(" -m vsgjax.train " in line for line in lines)
    script = sbatch.read_text()
    for option in ("--array=0-1%2", "--partition=gpu", "--time=120", "--gpus-per-node=1"):
        assert f"#SBATCH {option}\n" in script
    assert "SLURM_ARRAY_TASK_ID + 1" in script and str(commands) in script
    assert subprocess.run(["bash", "-n", str(sbatch)]).returncode == 0
    assert os.access(sbatch, os.X_OK)


@pytest.mark.slow
def test_sbatch_script_stops_and_requeues_itself_on_usr1_and_the_requeue_resumes(
        definitions, tmp_path, child_env):
    """sbatch.sh run by bash as SLURM would run array task 0, with a fake ``scontrol``."""
    assert launch.main(launch_args("one", definitions, tmp_path, "--backend", "print")) == 0
    job = launch.make_jobs(load_experiment("one", "debug", paper_dir=definitions), tmp_path)[0]
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "scontrol").write_text(f'#!/bin/sh\necho "$@" >> {bin_dir / "calls"}\n')
    (bin_dir / "scontrol").chmod(0o755)
    env = dict(child_env, PATH=f"{bin_dir}:{child_env['PATH']}", SLURM_ARRAY_TASK_ID="0",
               SLURM_ARRAY_JOB_ID="77", SLURM_JOB_ID="78")
    script = ["bash", str(tmp_path / "one" / "sbatch.sh")]
    out = tmp_path / "task.out"
    with open(out, "w") as file:
        task = subprocess.Popen(script, env=env, stdout=file, stderr=subprocess.STDOUT)
    wait_for(lambda: launch.checkpoint_step(job.job_dir) is not None, task, out)
    task.send_signal(signal.SIGUSR1)  # SLURM's --signal=B:USR1@120
    assert task.wait(timeout=TIMEOUT) == 0, out.read_text()
    assert (bin_dir / "calls").read_text() == "requeue 77_0\n"
    stopped = launch.checkpoint_step(job.job_dir)
    assert f"SIGTERM: saved a checkpoint at env step {stopped}" in job.log.read_text()
    assert stopped < ONE
    again = subprocess.run(script, env=env, capture_output=True, text=True,
                           timeout=TIMEOUT)  # the requeued task
    assert again.returncode == 0, again.stdout[-3000:]
    assert headers(job.log) == 2
    assert f"resuming from ckpt-{stopped:012d}.ckpt" in job.log.read_text()
    assert launch.checkpoint_step(job.job_dir) == ONE


# --- seeds in one process -----------------------------------------------------------------------


PAIRS = """
description = "launcher test: two models x three seeds, two seeds to a process"
steps = 400
seeds = 3
seeds_per_process = 2

[[groups]]
tasks = ["bbs_basic"]
models = ["vsg", "dreamerv2"]
"""


def test_seeds_of_one_config_share_a_process_spread_over_host_devices(tmp_path):
    (tmp_path / "pairs.toml").write_text(PAIRS)
    experiment = load_experiment("pairs", "debug", paper_dir=tmp_path)
    assert experiment.seeds_per_process == 2
    jobs = launch.make_jobs(experiment, tmp_path)
    processes = launch.group_processes(jobs, 2, True, lambda job: None)
    assert [[job.name for job in p.jobs] for p in processes] == [
        ["bbs_basic/vsg/s0", "bbs_basic/vsg/s1"], ["bbs_basic/vsg/s2"],
        ["bbs_basic/dreamerv2/s0", "bbs_basic/dreamerv2/s1"], ["bbs_basic/dreamerv2/s2"]]
    pair, single = processes[0], processes[1]
    command = pair.command()
    assert command[command.index("--seeds") + 1] == "0,1"
    assert command[command.index("--logdir") + 1] == str(tmp_path / "pairs/bbs_basic/vsg/s{seed}")
    assert command[-2:] == ["train.steps=400", "train.devices=2"]
    flags = pair.env({"XLA_FLAGS": "--xla_dump_to=x"})["XLA_FLAGS"]
    assert flags == "--xla_dump_to=x --xla_force_host_platform_device_count=2"
    assert single.command() == jobs[2].command() and single.env({}) == {}
    unspread = launch.group_processes(jobs, 2, False, lambda job: None)[0]
    assert "train.devices=2" not in unspread.command() and unspread.env({}) == {}
    # seeds resume in lockstep: a seed with a checkpoint never joins one without
    resumed = launch.group_processes(jobs[:3], 3, True,
                                     lambda job: 4000 if job.run.seed == 1 else None)
    assert [[job.run.seed for job in p.jobs] for p in resumed] == [[0, 2], [1]]


class _RecordingRunner(launch.LocalRunner):
    """Starts a half-second sleep for each process; records its name and the host devices in
    use once it has started."""

    def _next(self, queue, running):
        self.running = running
        return super()._next(queue, running)

    def _start(self, process, env):
        in_use = sum(p.devices for p, _, _ in self.running.values()) + process.devices
        self.starts.append((process.name, in_use))
        sleep = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(0.5)"])
        return sleep, open(os.devnull, "w")


def test_a_lone_seed_starts_beside_the_next_lone_one_not_beside_a_pair(tmp_path):
    """Two seeds to a process over 2 host devices: the lone s2 of one model starts with the lone
    s2 of the next, ahead of that model's pair, and a pair never runs beside anything."""
    (tmp_path / "pairs.toml").write_text(PAIRS)
    jobs = launch.make_jobs(load_experiment("pairs", "debug", paper_dir=tmp_path), tmp_path)
    spread = _RecordingRunner(jobs, 1, 60.0, open(os.devnull, "w"), poll_s=0.05,
                              seeds_per_process=2, spread=True)
    queue = spread._queue()
    assert [p.devices for p in queue] == [2, 1, 2, 1]
    assert launch.next_to_start(queue[::2], 1, idle=False) is None
    assert launch.next_to_start(queue[::2], 0, idle=True) == 0
    spread.starts = []
    spread.run()
    assert spread.starts == [("bbs_basic/vsg/s{0,1}", 2), ("bbs_basic/vsg/s2", 1),
                             ("bbs_basic/dreamerv2/s2", 2), ("bbs_basic/dreamerv2/s{0,1}", 2)]
    in_order = _RecordingRunner(jobs, 1, 60.0, open(os.devnull, "w"), poll_s=0.05,
                                seeds_per_process=2, spread=False)
    in_order.starts = []
    in_order.run()
    assert in_order.starts == [("bbs_basic/vsg/s{0,1}", 1), ("bbs_basic/vsg/s2", 1),
                               ("bbs_basic/dreamerv2/s{0,1}", 1), ("bbs_basic/dreamerv2/s2", 1)]


def test_a_bad_seeds_per_process_is_an_error_naming_it(tmp_path, capsys):
    (tmp_path / "pairs.toml").write_text(PAIRS.replace("= 2", "= 0"))
    assert launch.main(["pairs", "--definitions", str(tmp_path), "--root", str(tmp_path)]) == 2
    assert "seeds_per_process must be a positive integer, got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        launch.main(launch_args("one", tmp_path, tmp_path, "--seeds-per-process", "0"))
    assert "--seeds-per-process must be a positive integer, got 0" in capsys.readouterr().err


@pytest.mark.slow
def test_local_launch_trains_two_seeds_in_one_process(definitions, tmp_path, child_env):
    """``--seeds 2 --seeds-per-process 2``: one process trains both runs to the end; the second
    run's launch.log points at the first's, which holds the output."""
    args = launch_args("one", definitions, tmp_path, "--seeds", "2", "--steps", "280",
                       "--seeds-per-process", "2")  # the first update comes at env step 240
    result = subprocess.run([sys.executable, "-m", "experiments.launch", *args], cwd=ROOT,
                            env=child_env, capture_output=True, text=True, timeout=TIMEOUT)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    assert "started 0 bbs_basic/vsg/s{0,1}" in result.stdout
    first, second = (tmp_path / "one" / "bbs_basic" / "vsg" / f"s{seed}" for seed in (0, 1))
    assert launch.checkpoint_step(first) == launch.checkpoint_step(second) == 280
    log = (first / "launch.log").read_text()
    assert "--seeds 0,1" in log and "train.devices=2" in log
    assert "2 seed(s) in one program; mesh seed=2 x data=1" in log  # one seed per device
    assert (second / "launch.log").read_text().startswith(
        f"=== {log[4:23]} launch (local; output in {first / 'launch.log'}): ")


# --- bad input, config differences, --status ---------------------------------------------------


def test_unknown_names_are_errors_listing_the_valid_ones(definitions, tmp_path, capsys):
    assert launch.main(launch_args("nope", definitions, tmp_path)) == 2
    assert "unknown experiment 'nope'; valid: one, two, two_eval" in capsys.readouterr().err
    assert launch.main(launch_args("two", definitions, tmp_path, "--task", "bbs_large")) == 2
    assert "unknown task 'bbs_large' for experiment 'two'; valid: bbs_basic" in \
        capsys.readouterr().err
    assert launch.main(launch_args("two", definitions, tmp_path, "--model", "svsg")) == 2
    assert "valid: vsg, vsg-long" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        launch.main(launch_args("two", definitions, tmp_path, "--backend", "cloud"))
    assert exit_info.value.code == 2
    assert "choose from 'local', 'slurm', 'print'" in capsys.readouterr().err
    assert launch.main(launch_args("two", definitions, tmp_path, "--size", "huge")) == 2
    assert "unknown size 'huge'; valid: paper, small, cpu, debug" in capsys.readouterr().err
    assert not tmp_path.joinpath("two").exists()


def test_status_prints_the_table_and_launches_nothing(definitions, tmp_path, capsys):
    assert launch.main(launch_args("two", definitions, tmp_path, "--status")) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["#", "job", "state", "env", "steps", "score", "eta", "note"]
    assert lines[1].split() == ["0", "bbs_basic/vsg/s0", "new", f"0/{SHORT}"]
    assert lines[2].split() == ["1", "bbs_basic/vsg-long/s0", "new", f"0/{LONG}"]
    assert lines[-1] == "two: 2 jobs: 2 new"
    assert list(tmp_path.iterdir()) == []
    # an evaluate experiment whose source is untrained is blocked, naming the source run
    assert launch.main(launch_args("two_eval", definitions, tmp_path, "--status")) == 0
    out = capsys.readouterr().out
    assert out.count("blocked") == 3 and str(tmp_path / "two" / "bbs_basic" / "vsg" / "s0") in out


def test_kept_results_without_checkpoints_are_done_or_left_alone(definitions, tmp_path, capsys):
    """Results kept without their checkpoints and episodes (as committed under
    experiments/results/): a run evaluated to its steps is done, one short of them is never
    launched (training would start it over)."""
    experiment = load_experiment("two", "debug", paper_dir=definitions)
    short, long = launch.make_jobs(experiment, tmp_path)
    for job, last in ((short, SHORT), (long, LONG // 2)):
        job.job_dir.mkdir(parents=True)
        record = {"task": "bbs_basic", "method": "VSG", "seed": "0", "xs": [40.0, float(last)],
                  "ys": [1.5, 2.5]}
        (job.job_dir / "scores.jsonl").write_text(json.dumps(record) + "\n")
    assert (launch.job_status(short).state, launch.job_status(short).note) == (
        "done", "its checkpoints are not here")
    assert launch.job_status(long).state == "results only"
    before = snapshot(tmp_path)
    assert launch.main(launch_args("two", definitions, tmp_path, "--backend", "local")) == 1
    out = capsys.readouterr().out
    assert "skipped: finished before this launch" in out
    assert "no checkpoint to resume from; vsgjax.train --restart" in out
    assert out.splitlines()[-1] == "two: 2 jobs: 1 done, 1 results only"
    assert snapshot(tmp_path) == before  # nothing launched, nothing written


def test_a_run_dir_with_another_config_is_reported_and_left_alone(definitions, tmp_path,
                                                                  capsys):
    experiment = load_experiment("one", "debug", paper_dir=definitions)
    job = launch.make_jobs(experiment, tmp_path)[0]
    job.job_dir.mkdir(parents=True)
    other = make_config("bbs_basic", "vsg", "debug", ["model.deter=64", "env.time_limit=200"])
    text = json.dumps(to_dict(other))
    (job.job_dir / "config.json").write_text(text)
    assert launch.main(launch_args("one", definitions, tmp_path, "--backend", "local")) == 1
    out = capsys.readouterr().out
    assert "config differs" in out and "model.deter: 64 -> 32" in out
    assert sorted(p.name for p in job.job_dir.iterdir()) == ["config.json"]  # not launched
    assert (job.job_dir / "config.json").read_text() == text
    # a different train section alone is a resumable run, not a different config
    same = make_config("bbs_basic", "vsg", "debug", [*json.loads(OVERRIDES), "train.steps=7"])
    (job.job_dir / "config.json").write_text(json.dumps(to_dict(same)))
    assert launch.job_status(job).state == "new"


def test_a_group_caps_the_seeds_and_the_memory_experiment_resolves():
    """``cpu_memory``: 3 seeds per variant model and for the DrQ-v2 controls, 2 for the
    DreamerV2 memoryless controls and the tuning trial, 3 for SVSG and DreamerV1; every run's
    config (variant options included) resolves."""
    experiment = load_experiment("cpu_memory")
    seeds = {}
    for run in experiment.runs:
        seeds.setdefault((run.task, run.method), []).append(run.seed)
        run.config()
    assert seeds[("mjx_cartpole_swingup", "VSG-hidevel")] == [0, 1, 2]
    assert seeds[("mjx_cartpole_swingup", "DreamerV2-hidevel-memoryless")] == [0, 1]
    assert ("mjx_reacher_easy", "DreamerV2-memoryless") not in seeds
    assert seeds[("mjx_cartpole_swingup", "DreamerV2-memoryless-starts")] == [0, 1]
    assert seeds[("mjx_reacher_easy", "DrQ-v2-target10")] == [0, 1, 2]
    assert seeds[("mjx_cartpole_swingup", "VSG-hidevel-kappa05")] == [0, 1]
    assert seeds[("mjx_walker_walk", "SVSG")] == [0, 1, 2]
    tuned = {run.method: run.config().wm for run in experiment.runs if run.seed == 0
             and run.method.startswith("VSG-hidevel")}
    assert {method: (wm.gate_kappa, wm.kl_scale) for method, wm in tuned.items()} == {
        "VSG-hidevel": (0.4, 1.0), "VSG-hidevel-kappa05": (0.5, 1.0),
        "VSG-hidevel-kappa03": (0.3, 1.0)}
    controls = {run.method: run.config().ac for run in experiment.runs
                if run.seed == 0 and "memoryless" in run.method}
    assert {method: (ac.memoryless, ac.memoryless_starts) for method, ac in controls.items()
            if method.startswith("DreamerV2-memoryless")} == {
        "DreamerV2-memoryless": (True, False), "DreamerV2-memoryless-starts": (True, True)}
    posonce = {run.method: run.config().env for run in experiment.runs
               if run.method.endswith("-posonce")}
    assert set(posonce) == {"VSG-posonce", "DreamerV2-posonce", "DrQ-v2-posonce"}
    assert {(env.show_keys, env.show_steps) for env in posonce.values()} == {("position", 1)}
    assert seeds[("mjx_cartpole_swingup", "DrQ-v2-posonce")] == [0, 1, 2]
    assert len(experiment.runs) == 3 * 2 * 3 + 3 * 3 + 2 * 4 + 3 * 2 + 2 * 2 + 2 * 2 * 3
    assert len(load_experiment("cpu_memory", seeds=1).runs) == 3 * 2 + 3 + 4 + 2 + 2 + 2 * 2
