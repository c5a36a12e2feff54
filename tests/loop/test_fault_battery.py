"""A fault battery: both training loops killed with SIGKILL at chosen points of a run, then
resumed with the same command line to the end (CPU, ``debug`` size).

Each kill is deterministic: a driver (``python -c DRIVER``) patches one package function to
SIGKILL its own process at its n-th call, then calls ``vsgjax.train.main``; nothing in the
package knows about it. The kill points (:data:`KILL_POINTS`), per loop:

- ``prefill``: host loop: while writing the 2nd episode file of the prefill (half of its
  temporary file on disk); device loop: in the 2nd (prefill) call of the compiled program.
  The rerun starts over, the killed attempt's files moved to ``previous/``, and ends its
  prefill as the uninterrupted run does (the same env step and replay);
- ``update``: host loop: in the 4th update (its result computed, not returned); device loop:
  in the 2nd training call of the compiled program (the updates run inside it);
- ``checkpoint``: while writing the 2nd checkpoint (half of its temporary file on disk);
- ``evaluation``: in the 3rd evaluation (host: its episode finished, not yet returned;
  device: the compiled evaluation call returned, its result not recorded).

Each resumed run must finish (exit 0) with ``scores.jsonl`` holding every evaluation once on
the uninterrupted run's grid, every episode file complete (the temporary file of a killed
write never read), the replay the resume reports equal to the checkpoint's episodes,
``episodes/`` holding the checkpoint's episode files first (those written after the checkpoint
moved to ``previous/``, not fed to the resumed run), ``metrics.jsonl`` strictly increasing per
kind of record, and a final checkpoint that loads.
The device loop resumes exactly: its scores, metrics, final checkpoint and episode files must
equal the uninterrupted run's. The host loop does not checkpoint its envs: the episode each
env was running at the checkpoint is dropped and started over, so its ``episodes/`` may end
with fewer episodes than the uninterrupted run's, at most one per env and resume while episodes
run to the time limit (on this grid the counts happen to agree).

Cost: the subprocesses share one persistent XLA compilation cache, and each process runs
two of the battery's runs: it resumes the run the previous process left killed, to the end,
then starts the next kill point's run in a fresh log directory, which dies. The first process
runs the uninterrupted reference run before its faulty one. So a loop's 4 kills and 4 resumes
take 5 processes, and a process pays for tracing the compiled programs once. The two loops'
batteries run side by side (one driver process of each at a time).
"""

from __future__ import annotations

import concurrent.futures
import dataclasses
import functools
import hashlib
import itertools
import json
import re
import subprocess
import sys
import time
from pathlib import Path

import jax
import numpy as np
import pytest

from tests.support.subprocess_env import subprocess_env
from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.analysis.evaluation import evaluate_logdir
from vsgjax.config import make_config
from vsgjax.data import checkpoint
from vsgjax.data.replay.store import read_episode
from vsgjax.envs.mjx import make_mjx_task
from vsgjax.loop.device_program import DeviceProgram
from vsgjax.loop.run_state import checkpoint_tree

ROOT = Path(__file__).resolve().parents[2]
RUN_TIMEOUT = 900
SIGKILLED = -9  # a subprocess's return code after SIGKILL
CLOCKS = ("wall_s", "cpu_s", "steps_per_s")  # record keys that differ between runs

# bbs_basic, 104 env steps per episode (27 stored steps), chunks of 40 env steps: prefill
# ends at 240 with 2 episodes; updates 1-2 at 240, then one per chunk (6 in all); evaluations
# at 240, 320, 400; checkpoints at 240 (after update 2), 320 (4) and 400 (6).
HOST_EPISODE = (104, 27)  # env steps, stored steps
HOST = ("bbs_basic", ["env.time_limit=100", "train.prefill=240", "train.train_every=10",
                      "train.steps=400", "train.eval_every=80", "train.ckpt_every=2",
                      "train.video_every=100000"])
# mjx_cartpole_balance, 2 envs x 20 agent steps (80 env steps) per call: 2 prefill calls,
# then 3 training calls of 4 updates each; evaluations and checkpoints at 240, 320, 400.
DEVICE = ("mjx_cartpole_balance", ["env.time_limit=40", "env.num_envs=2", "train.length=8",
                                   "train.batch=3", "train.train_every=5", "train.prefill=160",
                                   "train.pretrain=0", "train.steps=400", "train.eval_every=80",
                                   "train.ckpt_every=4"])
LOOPS = {"host": HOST, "device": DEVICE}
GRID = [240, 320, 400]  # the evaluations of both loops' runs (env steps)
FINAL_STEP = 400


@dataclasses.dataclass(frozen=True)
class Kill:
    """A fault: SIGKILL at the ``n``-th call of what ``patch`` names (see DRIVER), and what the
    killed run leaves: its checkpoints and its evaluations in ``scores.jsonl`` (env steps)."""

    loop: str
    point: str  # prefill, update, checkpoint, evaluation
    patch: str
    n: int
    checkpoints: tuple[int, ...]
    scores: tuple[int, ...]

    @property
    def id(self) -> str:
        return f"{self.loop}-{self.point}"

    @property
    def resumes_from(self) -> int | None:
        """The checkpoint the resume starts from (None: a new run)."""
        return self.checkpoints[-1] if self.checkpoints else None


# Temporary files of checkpoint.atomic_write: ".<name>.<random>.tmp" beside <name>.
CKPT_TEMP, EPISODE_TEMP = r"\.ckpt-\d+\.ckpt\..+\.tmp", r"\..+\.mcap\..+\.tmp"
KILL_POINTS = [
    Kill("host", "prefill", f"write:{EPISODE_TEMP}", 2, (), ()),
    Kill("host", "update", "host_update", 4, (240,), (240,)),
    # the evaluation at 320 is recorded before the checkpoint at 320 dies: the resume from 240
    # must drop it and evaluate at 320 once more
    Kill("host", "checkpoint", f"write:{CKPT_TEMP}", 2, (240,), (240, 320)),
    Kill("host", "evaluation", "host_evaluation", 3, (240, 320), (240, 320)),
    Kill("device", "prefill", "device_call:prefill", 2, (), ()),
    Kill("device", "update", "device_call:training", 2, (240,), (240,)),
    Kill("device", "checkpoint", f"write:{CKPT_TEMP}", 2, (240,), (240, 320)),
    Kill("device", "evaluation", "device_evaluation", 3, (240, 320), (240, 320)),
]
assert len(KILL_POINTS) == 8  # fault injections: 4 kill points x 2 loops

# argv[1]: a JSON list of runs [{"argv": [...], "patch": str | null, "n": int}]; each run is
# ``vsgjax.train.main(argv)``, its patch (if any) installed just before it. Markers on stdout
# and stderr: "@@ run <i>" before run i, "@@ exit <code>" after it, "@@ SIGKILL <where>" just
# before a patch kills the process; "@@ cpu <seconds>" on stderr: the process's CPU time.
DRIVER = r'''
import json, os, re, resource, signal, sys

def cpu_line():
    usage = resource.getrusage(resource.RUSAGE_SELF)
    print(f"@@ cpu {usage.ru_utime + usage.ru_stime:.1f}", file=sys.stderr, flush=True)

def die(where):
    for stream in (sys.stdout, sys.stderr):
        print(f"@@ SIGKILL {where}", file=stream, flush=True)
    cpu_line()
    os.kill(os.getpid(), signal.SIGKILL)

def counter(n):
    """A function that returns True at its n-th call, and only then."""
    calls = [0]
    def due():
        calls[0] += 1
        return calls[0] == n
    return due

def kill_in_write(pattern, n):
    """The n-th write by checkpoint.atomic_write whose temporary file's name matches pattern
    writes half its bytes, fsyncs them and SIGKILLs the process (the real atomic_write, with
    its own temporary file, up to the write)."""
    from vsgjax.data import checkpoint
    real_os, due = os, counter(n)

    class HalfFile:
        def __init__(self, file, name):
            self.file, self.name = file, name
        def __enter__(self):
            return self
        def __exit__(self, *exc):
            self.file.close()
        def write(self, data):
            self.file.write(data[: len(data) // 2])
            self.file.flush()
            real_os.fsync(self.file.fileno())
            die(f"writing {self.name}: {len(data) // 2} of {len(data)} bytes")

    class Os:
        def __getattr__(self, name):
            return getattr(real_os, name)
        def fdopen(self, fd, *args, **kwargs):
            file = real_os.fdopen(fd, *args, **kwargs)
            name = real_os.path.basename(real_os.readlink(f"/proc/self/fd/{fd}"))
            return HalfFile(file, name) if re.fullmatch(pattern, name) and due() else file

    checkpoint.os = Os()

def kill_in_host_update(n):
    """The host loop's n-th update computes its result and dies before returning it."""
    import jax
    from vsgjax.loop import parallel
    init, due = parallel.Parallel.__init__, counter(n)

    def patched_init(self, *args, **kwargs):
        init(self, *args, **kwargs)
        train_step = self.train_step
        def killing_train_step(*step_args):
            result = train_step(*step_args)
            if due():
                jax.block_until_ready(result)
                die(f"in update {n} (its result computed, not returned)")
            return result
        self.train_step = killing_train_step

    parallel.Parallel.__init__ = patched_init

def kill_in_host_evaluation(n):
    """The host loop's n-th evaluation dies when its episode has finished."""
    from vsgjax.loop.evaluator import Evaluator
    run, on_episode, due = Evaluator.run, Evaluator._on_episode, counter(n)

    def patched_run(self, *args, **kwargs):
        self.kill_now = due()
        return run(self, *args, **kwargs)

    def patched_on_episode(self, *args):
        on_episode(self, *args)
        if getattr(self, "kill_now", False):
            die(f"in evaluation {n} (its episode finished, not returned)")

    Evaluator.run, Evaluator._on_episode = patched_run, patched_on_episode

def kill_in_device_call(which, n):
    """The device loop's n-th call of a compiled program ("prefill" or "training" episode
    call, or "evaluation") runs, then the process dies before the call returns."""
    import jax
    from vsgjax.loop import device_trainer
    programs, due = device_trainer.jitted_programs, counter(n)

    def killing(call, name):
        def wrapped(*args):
            result = call(*args)
            if due():
                jax.block_until_ready(result)
                die(f"in {name} call {n} of the compiled program (it ran, not returned)")
            return result
        return wrapped

    def patched(program, seeds, devices):
        episode, pretrain, evaluate = programs(program, seeds, devices)
        episode = dict(episode)
        if which == "evaluation":
            evaluate = killing(evaluate, which)
        else:
            training = which == "training"
            episode[training] = killing(episode[training], which)
        return episode, pretrain, evaluate

    device_trainer.jitted_programs = patched

def install(patch, n):
    kind, _, arg = patch.partition(":")
    if kind == "write":
        kill_in_write(arg, n)
    elif kind == "host_update":
        kill_in_host_update(n)
    elif kind == "host_evaluation":
        kill_in_host_evaluation(n)
    elif kind == "device_call":
        kill_in_device_call(arg, n)
    elif kind == "device_evaluation":
        kill_in_device_call("evaluation", n)
    else:
        raise ValueError(f"unknown patch {patch!r}")

from vsgjax import train

for index, run in enumerate(json.loads(sys.argv[1])):
    for stream in (sys.stdout, sys.stderr):
        print(f"@@ run {index}", file=stream, flush=True)
    if run["patch"]:
        install(run["patch"], run["n"])
    code = train.main(run["argv"])
    for stream in (sys.stdout, sys.stderr):
        print(f"@@ exit {code}", file=stream, flush=True)
cpu_line()
'''


def train_argv(loop: str, logdir: Path) -> list[str]:
    task, overrides = LOOPS[loop]
    return ["--task", task, "--model", "vsg", "--size", "debug", "--seed", "0", "--logdir",
            str(logdir), "--no-progress", *overrides]


def segments(text: str) -> dict[int, str]:
    """A driver's output split at its "@@ run <i>" markers."""
    parts = re.split(r"^@@ run (\d+)\n", text, flags=re.M)
    return {int(i): body for i, body in zip(parts[1::2], parts[2::2], strict=True)}


@dataclasses.dataclass
class Run:
    """One ``train.main`` call of a driver process: its output and how it ended."""

    out: str
    err: str
    exit_code: int | None  # None: the process died in it
    killed: str | None  # the driver's "@@ SIGKILL ..." line


def parse_runs(out: str, err: str, count: int) -> list[Run]:
    outs, errs = segments(out), segments(err)
    runs = []
    for i in range(count):
        body = outs.get(i, "")
        code = re.search(r"^@@ exit (-?\d+)$", body, flags=re.M)
        killed = re.search(r"^@@ SIGKILL (.*)$", body, flags=re.M)
        runs.append(Run(body, errs.get(i, ""), int(code.group(1)) if code else None,
                        killed.group(1) if killed else None))
    return runs


def run_driver(plan: list[dict], env: dict) -> tuple[int, list[Run], tuple[float, float]]:
    """Run a driver process: its return code, its runs, its wall and CPU seconds."""
    started = time.monotonic()
    done = subprocess.run([sys.executable, "-c", DRIVER, json.dumps(plan)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=RUN_TIMEOUT)
    cpu = re.findall(r"^@@ cpu (\S+)$", done.stderr, flags=re.M)
    return done.returncode, parse_runs(done.stdout, done.stderr, len(plan)), (
        time.monotonic() - started, float(cpu[-1]) if cpu else float("nan"))


def temp_files(logdir: Path) -> list[str]:
    """The hidden temporary files of interrupted atomic writes, relative to ``logdir``."""
    return sorted(str(p.relative_to(logdir)) for p in logdir.rglob(".*.tmp"))


def episode_files(logdir: Path) -> tuple[list[tuple[str, int]], list[str]]:
    """``(name, length)`` of every episode file that reads back whole, and the names of those
    that do not."""
    complete, corrupt = [], []
    for path in sorted((logdir / "episodes").glob("*.mcap")):
        try:
            length = len(read_episode(path)["is_first"])
        except Exception:  # any failure to read it back: a broken file
            corrupt.append(path.name)
            continue
        assert path.stem.endswith(f"-{length}"), path  # the name says the length
        complete.append((path.name, length))
    return complete, corrupt


def disk_state(logdir: Path) -> dict:
    """What a run directory holds: checkpoints (env steps), temporary files, episode files
    (complete and corrupt) and the evaluations in scores.jsonl."""
    scores = logdir / "scores.jsonl"
    episodes, corrupt = episode_files(logdir)
    return {"checkpoints": [step for step, _ in checkpoint.list_checkpoints(
                logdir / "checkpoints")],
            "temp_files": temp_files(logdir), "episodes": episodes, "corrupt_episodes": corrupt,
            "scores": json.loads(scores.read_text())["xs"] if scores.exists() else None}


@dataclasses.dataclass
class Scenario:
    kill: Kill
    logdir: Path
    killed: Run | None = None
    at_kill: dict | None = None  # disk_state after the kill
    process_code: int | None = None  # the killed process's return code
    resumed: Run | None = None


@dataclasses.dataclass
class Battery:
    loop: str
    reference: Path
    reference_run: Run
    scenarios: dict[str, Scenario]
    seconds: list[tuple[float, float]]  # each driver process's wall and CPU seconds


def run_battery(loop: str, root: Path, env: dict) -> Battery:
    """The loop's reference run and kill points in 5 driver processes (module docstring)."""
    kills = [k for k in KILL_POINTS if k.loop == loop]
    reference = root / "reference"
    scenarios = {k.point: Scenario(k, root / k.point) for k in kills}
    reference_run, seconds = None, []
    previous: Scenario | None = None
    for scenario in [*scenarios.values(), None]:
        plan = []
        if previous is None:
            plan.append({"argv": train_argv(loop, reference), "patch": None, "n": 0})
        else:
            plan.append({"argv": train_argv(loop, previous.logdir), "patch": None, "n": 0})
        if scenario is not None:
            kill = scenario.kill
            plan.append({"argv": train_argv(loop, scenario.logdir), "patch": kill.patch,
                         "n": kill.n})
        code, runs, clocks = run_driver(plan, env)
        seconds.append(clocks)
        if previous is None:
            reference_run = runs[0]
        else:
            previous.resumed = runs[0]
        if scenario is not None:
            scenario.killed, scenario.process_code = runs[1], code
            scenario.at_kill = disk_state(scenario.logdir)
        previous = scenario
    return Battery(loop, reference, reference_run, scenarios, seconds)


@pytest.fixture(scope="module")
def batteries(tmp_path_factory) -> dict[str, Battery]:
    """Both loops' batteries, run side by side (one driver process of each at a time)."""
    env = subprocess_env()
    with concurrent.futures.ThreadPoolExecutor(len(LOOPS)) as pool:
        futures = {loop: pool.submit(run_battery, loop, tmp_path_factory.mktemp(loop), env)
                   for loop in LOOPS}
        return {loop: future.result() for loop, future in futures.items()}


# --- what every finished run must hold -----------------------------------------------------


def read_jsonl(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def check_finished(logdir: Path, run: Run) -> dict:
    """A run that finished at FINAL_STEP: evaluations once each on GRID, episodes complete, no
    temporary file read as data, metrics in order, checkpoints intact. Returns disk_state."""
    assert run.exit_code == 0 and run.killed is None, run.err[-3000:]
    assert f"done: {FINAL_STEP} env steps" in run.out
    state = disk_state(logdir)  # reads every episode file back whole
    scores = read_jsonl(logdir / "scores.jsonl")
    assert len(scores) == 1
    assert scores[0]["xs"] == GRID and len(scores[0]["ys"]) == len(GRID)
    assert all(len(scores[0][clock]) == len(GRID) for clock in ("wall_s", "cpu_s"))
    assert [r["step"] for r in read_jsonl(logdir / "eval_episodes.jsonl")] == GRID
    records = read_jsonl(logdir / "metrics.jsonl")
    steps = [r["step"] for r in records]
    assert steps == sorted(steps) and steps[-1] == FINAL_STEP
    for kind in ("train/updates", "eval/return", "gates/open"):
        kind_steps = [r["step"] for r in records if kind in r]
        assert kind_steps and all(a < b for a, b in itertools.pairwise(kind_steps)), kind
    assert [r["step"] for r in records if "eval/return" in r] == GRID
    assert state["episodes"] and state["corrupt_episodes"] == []
    assert state["checkpoints"][-1] == FINAL_STEP and len(state["checkpoints"]) >= 2
    for _, path in checkpoint.list_checkpoints(logdir / "checkpoints"):
        checkpoint.verify(path)  # header, length and CRC
    return state


def check_kill(scenario: Scenario) -> None:
    """The process died where the patch says and left what such a death leaves: the
    checkpoints and evaluations before it, each once, and half a temporary file for a write."""
    kill, at_kill = scenario.kill, scenario.at_kill
    assert scenario.process_code == SIGKILLED, scenario.killed.err[-3000:]
    assert scenario.killed.killed is not None and scenario.killed.exit_code is None
    if kill.patch.startswith("write:"):
        assert len(at_kill["temp_files"]) == 1, at_kill
        assert re.fullmatch(kill.patch.partition(":")[2], Path(at_kill["temp_files"][0]).name)
    else:
        assert at_kill["temp_files"] == []
    assert ("prefill done" in scenario.killed.out) == (kill.point != "prefill")
    assert at_kill["checkpoints"] == list(kill.checkpoints)
    assert at_kill["scores"] == list(kill.scores)
    assert at_kill["episodes"] and at_kill["corrupt_episodes"] == []


RESUME = re.compile(r"^resuming from ckpt-(\d+)\.ckpt: env step (\d+), update (\d+)", re.M)
HOST_REPLAY = re.compile(r"replay (\d+) steps in (\d+) episodes")


def check_resume_line(scenario: Scenario) -> str:
    """The resumed run says where it resumed from, and what of the killed run it moved to
    previous/: a run killed before its first checkpoint starts over as a new one, its files
    moved aside; a resumed host loop's replay is the episodes of its checkpoint, those the
    killed run wrote after it moved aside."""
    kill, out, at_kill = scenario.kill, scenario.resumed.out, scenario.at_kill
    if kill.resumes_from is None:
        assert f"{scenario.logdir} held an attempt killed before its first checkpoint" in out
        return next(line for line in out.splitlines() if line.startswith("starting a new run"))
    match = RESUME.search(out)
    assert match, out[-2000:]
    line = out[match.start():].splitlines()[0]
    assert int(match.group(1)) == int(match.group(2)) == kill.resumes_from
    if kill.loop == "host":
        steps, episodes = map(int, HOST_REPLAY.search(line).groups())
        env_steps, stored = HOST_EPISODE
        assert episodes == kill.resumes_from // env_steps and steps == episodes * stored
        later = len(at_kill["episodes"]) - episodes
        if later:
            assert (f"moved {later} episode file(s) written after ckpt-"
                    f"{kill.resumes_from:012d}.ckpt by the interrupted run") in out
    return line


def prefill_line(run: Run) -> str:
    return next(line for line in run.out.splitlines() if line.startswith("prefill done"))


@functools.cache
def restore_target(loop: str):
    """The checkpoint tree of a run of ``loop``'s config (shapes only)."""
    task, overrides = LOOPS[loop]
    config = make_config(task, "vsg", "debug", overrides)
    key = jax.random.PRNGKey(0)
    if loop == "host":
        agent = DreamerAgent(config, (64, 64, 3), 2, False)
        return checkpoint_tree(jax.eval_shape(agent.init, key),
                               key)
    env = config.env
    program = DeviceProgram(config, make_mjx_task(task, env.action_repeat, env.time_limit))
    return {"loop": jax.eval_shape(program.init, key)}


def assert_trees_equal(a, b) -> None:
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


def metrics_without_clocks(logdir: Path) -> list[dict]:
    return [{k: v for k, v in r.items() if not k.endswith(CLOCKS)}
            for r in read_jsonl(logdir / "metrics.jsonl")]


def digest(episode: dict) -> str:
    """A hash of an episode's keys and arrays (equal episodes, equal digests)."""
    hashed = hashlib.sha256()
    for key in sorted(episode):
        hashed.update(key.encode() + np.ascontiguousarray(episode[key]).tobytes())
    return hashed.hexdigest()


def file_digests(logdir: Path) -> list[str]:
    return [digest(read_episode(path)) for path in sorted((logdir / "episodes").glob("*.mcap"))]


def replay_digests(state) -> list[str]:
    """Every episode a device loop state's replay holds, oldest first (none overwritten)."""
    data, stored = jax.device_get(state.replay.data), int(state.replay.stored)
    assert stored <= data["reward"].shape[0]
    return [digest({k: v[slot, env] for k, v in data.items()})
            for slot in range(stored) for env in range(data["reward"].shape[1])]


# --- the tests ------------------------------------------------------------------------------


# The first test to run starts both batteries (~4 minutes of a 2-core machine's time; more on a
# busy one): a limit above the suite's 15 minutes for a stuck test.
pytestmark = pytest.mark.timeout(1800)


@pytest.mark.slow
@pytest.mark.parametrize("loop", list(LOOPS))
def test_the_uninterrupted_reference_run(batteries, loop):
    battery = batteries[loop]
    print(f"{loop}: driver processes took (wall, CPU) " + ", ".join(
        f"({wall:.0f} s, {cpu:.0f} s)" for wall, cpu in battery.seconds))
    state = check_finished(battery.reference, battery.reference_run)
    assert "starting a new run" in battery.reference_run.out and state["temp_files"] == []
    if loop == "device":  # the replay is every episode written, once, in order
        assert "loop=device" in battery.reference_run.out.splitlines()[0]
        restored = checkpoint.restore(battery.reference / "checkpoints", restore_target(loop))
        assert replay_digests(restored.tree["loop"]) == file_digests(battery.reference)
    # python -m vsgjax.evaluate reads the run's newest checkpoint (the device loop's: the
    # agent inside its loop state)
    infos, step = evaluate_logdir(battery.reference, episodes=1)
    assert step == FINAL_STEP and len(infos) == 1 and np.isfinite(infos[0]["return"])


@pytest.mark.slow
@pytest.mark.parametrize("kill", KILL_POINTS, ids=lambda k: k.id)
def test_sigkill_then_resume_finishes_with_every_evaluation_once(batteries, kill):
    battery = batteries[kill.loop]
    scenario = battery.scenarios[kill.point]
    check_kill(scenario)
    line = check_resume_line(scenario)
    at_kill = scenario.at_kill
    print(f"{kill.id}: killed {scenario.killed.killed}; left checkpoints "
          f"{at_kill['checkpoints']}, evaluations {at_kill['scores']}, "
          f"{len(at_kill['episodes'])} episodes, temporary files {at_kill['temp_files']}; "
          f"resume: {line}")
    state = check_finished(scenario.logdir, scenario.resumed)
    # the killed write's temporary file was never read as data, and the resumed run removed it
    assert state["temp_files"] == []
    # nothing lost: what the killed run wrote is in episodes/ or moved to previous/; nothing
    # mixed: episodes/ starts with the checkpoint's episodes, and holds as many as the
    # uninterrupted run's (the host loop: up to one fewer per env, its envs restarted)
    moved = {p.name for p in (scenario.logdir / "previous").rglob("episodes/*.mcap")}
    assert {name for name, _ in at_kill["episodes"]} <= {n for n, _ in state["episodes"]} | moved
    kept = at_kill["episodes"][:kill.resumes_from // HOST_EPISODE[0]] if (
        kill.loop == "host" and kill.resumes_from) else []
    assert state["episodes"][:len(kept)] == kept
    uninterrupted = len(disk_state(battery.reference)["episodes"])
    restarted_envs = 1 if kill.loop == "host" and kill.resumes_from else 0  # env.num_envs=1
    assert uninterrupted - restarted_envs <= len(state["episodes"]) <= uninterrupted
    if kill.resumes_from is None:  # started over: prefill ends as the uninterrupted run's
        assert prefill_line(scenario.resumed) == prefill_line(battery.reference_run)
    restored = checkpoint.restore(scenario.logdir / "checkpoints", restore_target(kill.loop))
    assert restored.step == FINAL_STEP
    if kill.loop == "host":
        return
    # the device loop resumes exactly: the uninterrupted run's scores, metrics, final state
    reference = battery.reference
    assert (json.loads((scenario.logdir / "scores.jsonl").read_text())["ys"]
            == json.loads((reference / "scores.jsonl").read_text())["ys"])
    assert metrics_without_clocks(scenario.logdir) == metrics_without_clocks(reference)
    whole = checkpoint.restore(reference / "checkpoints", restore_target(kill.loop))
    assert_trees_equal(restored.tree, whole.tree)  # agent, optimiser, device replay, key
    counters = [{k: v for k, v in c.meta["counters"].items() if k not in ("wall_s", "cpu_s")}
                for c in (restored, whole)]
    assert counters[0] == counters[1]
    # episodes/ holds the replay's episodes once each, in order: those the killed run wrote
    # after its last checkpoint were rewritten by the resumed run under the same numbers
    assert file_digests(scenario.logdir) == replay_digests(restored.tree["loop"])
    if kill.resumes_from is not None:
        assert "prefill done" not in scenario.resumed.out  # the device replay came back whole
