"""The run directory under faults and bad inputs: nothing lost, nothing mixed, no tracebacks.

Each case of the fault table: corrupt checkpoints, another run's data, a second process, a
log directory that cannot be written, a failing write, bad values and flags. The run directory
of a real (tiny) run is tests/fixtures/rundir_v1's bbs run; the rest is written here.
"""

from __future__ import annotations

import errno
import json
import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

import bbs
import vsgjax
from experiments import launch, report
from tests.support.overrides import replaced
from tests.support.registry_names import example_tasks, one_model_per_agent
from vsgjax import evaluate, train
from vsgjax.agents.dreamer.agent import DreamerAgent
from vsgjax.config import ConfigError, config_changes, make_config, to_dict
from vsgjax.data import checkpoint
from vsgjax.data.replay import EpisodeStore
from vsgjax.data.replay.store import read_episode
from vsgjax.envs import make_device_task
from vsgjax.loop.device_program import DeviceProgram
from vsgjax.loop.host_trainer import first_update
from vsgjax.loop.run_state import checkpoint_tree
from vsgjax.loop.rundir import RunWriter
from vsgjax.loop.rundir_guard import FOREIGN_DIR, LOCK_FILE, PREVIOUS_DIR, RunDirError
from vsgjax.registry.agents import agent_entry
from vsgjax.registry.tasks import family_of

ROOT = Path(__file__).resolve().parents[2]
FIXTURE = ROOT / "tests" / "fixtures" / "rundir_v1" / "bbs_basic-vsg-debug"
MJX_FIXTURE = FIXTURE.parent / "mjx_cartpole_swingup-vsg-debug"
OVERRIDES = ["env.time_limit=200", "train.eval_every=200", "train.ckpt_every=100"]
FLAGS = ["--task", "bbs_basic", "--model", "vsg", "--size", "debug", "--no-progress"]
CKPT = "ckpt-000000000320.ckpt"


@pytest.fixture
def old_run(tmp_path) -> Path:
    """A copy of a finished tiny run (one checkpoint at env step 320, one episode)."""
    logdir = tmp_path / "run"
    shutil.copytree(FIXTURE, logdir)
    return logdir


def config(*overrides: str):
    return make_config("bbs_basic", "vsg", "debug", [*OVERRIDES, *overrides])


def run_train(capsys, logdir: Path, *args: str) -> tuple[int, str, str]:
    """``vsgjax.train`` with FLAGS and OVERRIDES, of which ``args`` replace those it gives."""
    code = train.main([*FLAGS, "--logdir", str(logdir), *replaced(OVERRIDES, *args)])
    out, err = capsys.readouterr()
    return code, out, err


def one_line_error(err: str) -> str:
    """The one ``error: ...`` line a command printed to stderr (and nothing else)."""
    lines = err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    return lines[0]


def snapshot(logdir: Path) -> dict[str, bytes]:
    """Every file under ``logdir`` (but the lock) and its bytes."""
    return {str(p.relative_to(logdir)): p.read_bytes() for p in sorted(logdir.rglob("*"))
            if p.is_file() and p.name != LOCK_FILE}


def save_checkpoints(logdir: Path, steps: list[int], trained=None) -> None:
    """Checkpoints of a stand-in tree, each holding the config it was ``trained`` with
    (:func:`config` by default)."""
    meta = {"config": to_dict(trained or config())}
    for step in steps:
        checkpoint.save(logdir / "checkpoints", step, {"x": np.full(3, step)}, meta)


def with_config(logdir: Path, trained: dict, step: int = 320) -> Path:
    """The fixture's checkpoint (written before checkpoints held their config) as today's
    training writes it, holding the config ``trained``, saved as the checkpoint of ``step``
    in ``logdir``."""
    key = jax.random.PRNGKey(0)
    target = checkpoint_tree(jax.eval_shape(DreamerAgent(config(), (64, 64, 3), 2, False).init,
                                            key), key)
    tree, meta = checkpoint.load(FIXTURE / "checkpoints" / CKPT, target)
    path = checkpoint.checkpoint_path(logdir / "checkpoints", step)
    path.parent.mkdir(exist_ok=True)
    return checkpoint.atomic_write(path, checkpoint.encode(tree, {**meta, "config": trained}))


def saved_config(logdir: Path) -> dict:
    return json.loads((logdir / "config.json").read_text())


# --- corrupt checkpoints ---------------------------------------------------------------------


def test_every_checkpoint_corrupt_is_refused_and_nothing_changes(old_run, capsys):
    path = old_run / "checkpoints" / CKPT
    path.write_bytes(path.read_bytes()[:1000])  # truncated
    before = snapshot(old_run)
    code, _, err = run_train(capsys, old_run)
    assert code == 2
    line = one_line_error(err)
    assert f"every checkpoint of {old_run} is corrupt ({path}: payload has" in line
    assert "nothing was changed; rerun with --restart" in line
    assert snapshot(old_run) == before


def test_restart_moves_the_old_contents_aside_and_deletes_nothing(old_run):
    (old_run / "checkpoints" / CKPT).write_bytes(b"garbage")
    before = snapshot(old_run)
    run = RunWriter(config(), old_run, restart=True)
    try:
        assert run.moved_to.parent == old_run / PREVIOUS_DIR
        assert snapshot(run.moved_to) == before
        assert sorted(p.name for p in old_run.iterdir()) == [LOCK_FILE, "episodes",
                                                              PREVIOUS_DIR]
        assert not run.checkpoints() and not run.episode_paths()
    finally:
        run.close()
    again = RunWriter(config(), old_run, restart=True)  # a second restart keeps the first
    again.close()
    assert len(list((old_run / PREVIOUS_DIR).iterdir())) == 2


def test_one_corrupt_checkpoint_is_set_aside_and_not_counted_among_the_kept(tmp_path):
    save_checkpoints(tmp_path, [10, 20, 30])
    bad = checkpoint.checkpoint_path(tmp_path / "checkpoints", 40)
    bad.write_bytes(b"not a checkpoint")
    with pytest.warns(UserWarning, match=f"corrupt checkpoint {bad} .* moved to"):
        run = RunWriter(config(), tmp_path)
    try:
        assert [step for step, _ in run.checkpoints()] == [10, 20, 30]
        assert (tmp_path / "checkpoints" / "corrupt" / bad.name).read_bytes() == (
            b"not a checkpoint")
        save_checkpoints(tmp_path, [50])
        assert [step for step, _ in run.checkpoints()] == [20, 30, 50]  # 3 kept, all good
        assert (tmp_path / "checkpoints" / "corrupt" / bad.name).exists()
    finally:
        run.unlock()


def test_a_run_with_a_corrupt_newest_checkpoint_resumes_from_the_one_before(old_run, capsys):
    good = old_run / "checkpoints" / CKPT
    newer = checkpoint.checkpoint_path(old_run / "checkpoints", 400)
    newer.write_bytes(good.read_bytes()[:-10])
    with pytest.warns(UserWarning, match="moved to"):
        code, out, err = run_train(capsys, old_run, "train.steps=320")
    assert code == 0, err
    assert f"resuming from {CKPT}: env step 320" in out
    assert (old_run / "checkpoints" / "corrupt" / newer.name).exists()
    assert [p.name for _, p in checkpoint.list_checkpoints(old_run / "checkpoints")] == [CKPT]


# --- another run's data, a second process ----------------------------------------------------


def test_another_seed_does_not_resume_a_run(old_run, capsys):
    before = snapshot(old_run)
    code, _, err = run_train(capsys, old_run, "--seed", "1")
    assert code == 2
    line = one_line_error(err)
    assert (f"{old_run} holds a run with a different config (train.seed: 0 -> 1); rerun with "
            "--restart to move the old contents to") in line and "or use another --logdir" in line
    assert snapshot(old_run) == before


def test_only_the_resumable_train_keys_may_change_on_resume(old_run, capsys):
    """train.steps and the cadences of logs, evaluations, checkpoints and videos may change;
    the data and the train ratio (train.batch, ...) make another run."""
    code, out, err = run_train(capsys, old_run, "train.steps=320", "train.eval_every=100",
                               "train.log_every=20", "train.video_every=1000",
                               "train.eval_episodes=2")
    assert code == 0 and "nothing to train" in out, err
    before = snapshot(old_run)
    code, _, err = run_train(capsys, old_run, "train.steps=320", "train.batch=2")
    assert code == 2 and "(train.batch: 4 -> 2)" in one_line_error(err)
    assert snapshot(old_run) == before


def test_the_seeds_of_one_process_keep_their_own_runs(tmp_path, capsys):
    """--seeds 0,1 resumes each seed's own run; when one seed's directory holds another seed's
    run, the process is refused before anything in any seed's directory is changed."""
    for seed in (0, 1):
        shutil.copytree(FIXTURE, tmp_path / f"s{seed}")
        shutil.rmtree(tmp_path / f"s{seed}" / "checkpoints")
        with_config(tmp_path / f"s{seed}", to_dict(config(f"train.seed={seed}")))
        (tmp_path / f"s{seed}" / "config.json").unlink()
    flags = [*FLAGS, "--seeds", "0,1", *OVERRIDES, "train.steps=320"]
    code = train.main([*flags, "--logdir", str(tmp_path / "s{seed}")])
    out, err = capsys.readouterr()
    assert code == 0 and "nothing to train" in out, err
    assert [saved_config(tmp_path / f"s{seed}")["train"]["seed"] for seed in (0, 1)] == [0, 1]
    shutil.rmtree(tmp_path / "s1")
    shutil.copytree(tmp_path / "s0", tmp_path / "s1")  # seed 0's run in seed 1's place
    left = tmp_path / "s0" / "checkpoints" / f".{CKPT}.abc123{checkpoint.TEMP_SUFFIX}"
    left.write_bytes(b"half a checkpoint")  # what seed 0's opening would remove
    before = {seed: snapshot(tmp_path / f"s{seed}") for seed in (0, 1)}
    code = train.main([*flags, "--logdir", str(tmp_path / "s{seed}")])
    line = one_line_error(capsys.readouterr().err)
    assert code == 2 and f"{tmp_path / 's1'} holds a run with a different config (train.seed: " \
                         "0 -> 1)" in line
    assert {seed: snapshot(tmp_path / f"s{seed}") for seed in (0, 1)} == before


def test_a_missing_config_json_is_rebuilt_from_the_checkpoint_not_the_command(old_run, capsys):
    trained = saved_config(old_run)
    with_config(old_run, trained)
    (old_run / "config.json").unlink()
    before = snapshot(old_run)
    code, _, err = run_train(capsys, old_run, "wm.kl_scale=0.5")
    assert code == 2
    assert (f"{old_run} holds a run with a different config (wm.kl_scale: "
            f"{trained['wm']['kl_scale']!r} -> 0.5) (its config as {CKPT} holds it: config.json "
            "is missing); rerun with --restart") in one_line_error(err)
    assert snapshot(old_run) == before
    code, out, err = run_train(capsys, old_run, "train.steps=320")
    assert code == 0, err
    assert (f"{old_run}: config.json is missing: the run's config is rebuilt from {CKPT}, the "
            "config it was trained with") in out
    assert config_changes(trained, saved_config(old_run)) == []


def test_a_missing_config_json_with_checkpoints_that_predate_it_is_refused(old_run, capsys):
    (old_run / "config.json").unlink()
    before = snapshot(old_run)
    code, _, err = run_train(capsys, old_run, "wm.kl_scale=0.5")
    assert code == 2
    assert (f"{old_run} has checkpoints ({CKPT}) but no config.json, and they were written "
            "before checkpoints held their config, so the run's config cannot be told; nothing "
            "was changed; restore config.json from a copy of the run, or rerun with --restart"
            ) in one_line_error(err)
    assert snapshot(old_run) == before


def test_restart_refuses_a_run_that_would_train_nothing_before_moving_anything(old_run, capsys):
    before = snapshot(old_run)
    code = train.main([*FLAGS, "--logdir", str(old_run), "--restart",
                       *replaced(OVERRIDES, "train.steps=100")])
    err = capsys.readouterr().err
    assert code == 2
    assert ("train.steps=100 ends before the run's first update, at env step 240 (prefill ends "
            "at env step 120") in one_line_error(err)
    assert "so starting over with --restart, it would train nothing" in err
    assert snapshot(old_run) == before and not (old_run / PREVIOUS_DIR).exists()


def test_another_runs_newest_checkpoint_is_set_aside_and_the_run_resumes_from_its_own(
        old_run, capsys):
    """Told by its config: moved to checkpoints/foreign/ with one line naming it."""
    other = saved_config(MJX_FIXTURE)
    foreign = with_config(old_run, other, step=400)
    code, out, err = run_train(capsys, old_run, "train.steps=320")
    assert code == 0, err
    moved = old_run / "checkpoints" / FOREIGN_DIR / foreign.name
    line = next(line for line in out.splitlines() if line.startswith(str(foreign)))
    assert line.startswith(f"{foreign} is not this run's checkpoint (its config differs from "
                           "the run's: ")
    assert line.endswith(f"): moved it to {moved}; the run resumes from its own newest "
                         "checkpoint") and len(line) < 400
    assert f"resuming from {CKPT}: env step 320" in out
    assert moved.exists() and [p.name for _, p in checkpoint.list_checkpoints(
        old_run / "checkpoints")] == [CKPT]


def test_another_runs_checkpoint_from_before_configs_is_told_by_its_arrays(old_run, capsys):
    """A checkpoint that holds no config and does not fit the model: the run falls back to its
    own older one (said, the other moved aside); when it is the only one, a short error names
    it and nothing is moved."""
    foreign = checkpoint.checkpoint_path(old_run / "checkpoints", 400)
    shutil.copy(MJX_FIXTURE / "checkpoints" / "ckpt-000000000240.ckpt", foreign)
    code, out, err = run_train(capsys, old_run, "train.steps=320")
    assert code == 0, err
    moved = old_run / "checkpoints" / FOREIGN_DIR / foreign.name
    assert (f"{foreign} is not this run's checkpoint (it does not fit this run's model: its "
            "tree is not this run's: ") in out
    assert f"moved it to {moved}; the run resumes from its own newest checkpoint" in out
    assert f"resuming from {CKPT}: env step 320" in out and moved.exists()
    (old_run / "checkpoints" / CKPT).unlink()
    shutil.copy(moved, foreign)
    code, _, err = run_train(capsys, old_run, "train.steps=320")
    line = one_line_error(err)
    assert code == 2 and line.startswith(f"error: checkpoint {foreign} does not fit this run ("
                                         "its tree is not this run's: ")
    assert line.endswith("is it another run's? move it out of the run's checkpoints/")
    assert len(line) < 400 and foreign.exists()


def test_episodes_of_another_config_without_a_checkpoint_are_refused(old_run, capsys):
    shutil.rmtree(old_run / "checkpoints")
    before = snapshot(old_run)
    code, _, err = run_train(capsys, old_run, "env.time_limit=400", "train.steps=1000")
    assert code == 2
    line = one_line_error(err)
    assert (f"{old_run} holds a run with a different config (env.time_limit: 200 -> 400); "
            "rerun with --restart") in line
    assert snapshot(old_run) == before


@pytest.mark.parametrize("episodes_kept", [False, True])
def test_evaluations_without_a_checkpoint_are_refused(old_run, capsys, episodes_kept):
    """Committed results (scores and logs, their checkpoints not kept), or a run whose
    checkpoints/ was deleted, are never trained over: that would start the run over and
    replace them."""
    shutil.rmtree(old_run / "checkpoints")
    if not episodes_kept:
        shutil.rmtree(old_run / "episodes")
    before = snapshot(old_run)
    code, _, err = run_train(capsys, old_run, "train.steps=400")
    assert code == 2
    line = one_line_error(err)
    assert (f"{old_run} holds the evaluations of a run to env step 320 but no checkpoint to "
            "resume it from (there is no checkpoints/); nothing was changed; rerun with "
            "--restart") in line
    assert snapshot(old_run) == before


def test_an_attempt_killed_before_its_first_checkpoint_is_moved_aside(old_run):
    """What a first attempt wrote before any checkpoint or evaluation (episodes, log lines) is
    moved to previous/, so the new run starts as an uninterrupted one; nothing is deleted."""
    shutil.rmtree(old_run / "checkpoints")
    (old_run / "scores.jsonl").write_text('{"xs": [], "ys": []}\n')
    before = snapshot(old_run)
    (old_run / "launch.log").write_text("# launch 2\n")  # open in the launcher: it stays
    run = RunWriter(config(), old_run)
    try:
        assert run.attempt_moved_to.parent == old_run / PREVIOUS_DIR
        assert snapshot(run.attempt_moved_to) == before
        assert not run.episode_paths() and not (old_run / "metrics.jsonl").exists()
        assert (old_run / "launch.log").read_text() == "# launch 2\n"
    finally:
        run.unlock()
    fresh = RunWriter(config(), old_run)  # an empty attempt moves nothing
    assert fresh.attempt_moved_to is None
    fresh.unlock()


def test_episodes_written_after_the_checkpoint_are_moved_aside_on_resume(old_run, capsys):
    """The fixture's checkpoint (env step 320) counts its one episode; a later one, written by
    the interrupted run, goes to previous/ and not into the resumed run's replay."""
    (kept,) = sorted((old_run / "episodes").glob("*.mcap"))
    later = old_run / "episodes" / f"29991231T000000000000-00000000-{kept.stem[-2:]}.mcap"
    shutil.copy(kept, later)
    code, out, err = run_train(capsys, old_run, "train.steps=320")
    assert code == 0, err
    assert "replay 52 steps in 1 episodes" in out
    assert (f"{old_run}: moved 1 episode file(s) written after {CKPT} by the interrupted run "
            f"to {old_run / PREVIOUS_DIR}") in out
    assert [p.name for p in (old_run / "episodes").glob("*.mcap")] == [kept.name]
    assert [p.name for p in (old_run / PREVIOUS_DIR).glob("*/episodes/*.mcap")] == [later.name]


def test_a_torn_last_log_line_is_reported_once_naming_file_and_line(old_run, capsys):
    metrics = old_run / "metrics.jsonl"
    lines = metrics.read_text().splitlines()
    metrics.write_text("\n".join(lines) + '\n{"step": 320, "eval/ret')
    with pytest.warns(UserWarning) as caught:
        code, _, err = run_train(capsys, old_run, "train.steps=320")
    assert code == 0, err
    torn = [str(w.message) for w in caught if "cut short" in str(w.message)]
    assert torn == [f"{metrics}, line {len(lines) + 1}: dropped a record cut short by a killed "
                    """run (23 characters: '{"step": 320, "eval/ret')"""]
    assert metrics.read_text().splitlines() == lines


def test_a_finished_run_asked_for_fewer_steps_says_so(old_run, capsys):
    scores = (old_run / "scores.jsonl").read_text()
    code, out, err = run_train(capsys, old_run, "train.steps=300")
    assert code == 0, err
    assert ("nothing to train: the run is already at env step 320, evaluated and saved "
            "(train.steps=300); a higher train.steps trains it further") in out
    assert (old_run / "scores.jsonl").read_text() == scores
    assert [p.name for _, p in checkpoint.list_checkpoints(old_run / "checkpoints")] == [CKPT]


def test_a_video_is_written_whole_and_a_killed_ones_temporary_file_removed(tmp_path):
    run = RunWriter(config(), tmp_path)
    run.open_logs(0)
    path = run.logger.video("eval", 200, np.zeros((4, 64, 64, 3), np.uint8))
    run.close()
    assert [p.name for p in path.parent.iterdir()] == [path.name] and path.stat().st_size
    left = path.parent / f".{path.name}.abc123{checkpoint.TEMP_SUFFIX}"
    left.write_bytes(b"half a video")
    save_checkpoints(tmp_path, [200])  # a run to resume: its directory is kept
    RunWriter(config(), tmp_path).unlock()
    assert not left.exists() and path.exists()


LOCKER = ("import sys, time; from pathlib import Path; "
          "from vsgjax.loop.rundir_guard import RunLock; "
          "lock = RunLock(Path(sys.argv[1])); print('locked', flush=True); time.sleep(120)")


def test_a_second_process_is_refused_naming_the_holder_and_a_killed_ones_lock_is_taken(
        tmp_path, capsys):
    holder = subprocess.Popen([sys.executable, "-c", LOCKER, str(tmp_path)], cwd=ROOT,
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        with pytest.raises(RunDirError, match=f"in use by another training process "
                                              f"\\(pid {holder.pid}, which holds"):
            RunWriter(config(), tmp_path)
        code, _, err = run_train(capsys, tmp_path)
        assert code == 2 and f"(pid {holder.pid}," in one_line_error(err)
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    run = RunWriter(config(), tmp_path)  # the killed holder's lock is taken over
    assert (tmp_path / LOCK_FILE).read_text().strip() == str(os.getpid())
    run.unlock()


def test_the_lock_is_released_when_a_trainer_fails_to_start(tmp_path):
    (tmp_path / "a").mkdir()
    (tmp_path / "b").write_text("a file")
    with pytest.raises(ValueError, match="is a file"):
        train.make_trainer([config(), config("train.seed=1")], [tmp_path / "a", tmp_path / "b"],
                           progress=False)
    RunWriter(config(), tmp_path / "a").unlock()  # seed 0's directory is free again


# --- log directories that cannot be written --------------------------------------------------


def test_a_log_dir_that_is_a_file_or_under_a_file_is_a_one_line_error(tmp_path, capsys):
    file = tmp_path / "file"
    file.write_text("x")
    for logdir, message in ((file, f"log directory {file} is a file"),
                            (file / "run", f"log directory {file / 'run'} is under the file "
                                           f"{file}")):
        code, _, err = run_train(capsys, logdir)
        assert code == 2 and message in one_line_error(err)
    assert file.read_text() == "x"


@pytest.fixture
def mount_tmpfs(tmp_path):
    """``mount(options) -> directory``: a tmpfs (skipped where this user cannot mount one)."""
    mounted = []

    def mount(options: str) -> Path:
        directory = tmp_path / f"mnt{len(mounted)}"
        directory.mkdir()
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(directory)],
                              capture_output=True)
        if done.returncode != 0:
            pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode().strip()}")
        mounted.append(directory)
        return directory

    yield mount
    for directory in mounted:
        subprocess.run(["umount", str(directory)], check=True)


def test_a_read_only_log_dir_is_a_one_line_error(mount_tmpfs, capsys):
    read_only = mount_tmpfs("ro,size=1m")
    for logdir in (read_only, read_only / "run"):
        code, _, err = run_train(capsys, logdir)
        assert code == 2
        assert f"log directory {logdir} cannot be" in one_line_error(err)
        assert "read-only or no permission" in err


# --- failing writes --------------------------------------------------------------------------


def test_a_full_disk_during_a_checkpoint_leaves_the_previous_one(mount_tmpfs):
    directory = mount_tmpfs("size=256k")
    checkpoint.save(directory, 10, {"x": np.zeros(1000)}, {})
    with pytest.raises(checkpoint.WriteError, match=r"cannot write .*ckpt-000000000020\.ckpt: "
                                                    "No space left on device"):
        checkpoint.save(directory, 20, {"x": np.zeros(100_000)}, {})
    assert [p.name for p in directory.iterdir()] == ["ckpt-000000000010.ckpt"]  # no temp file
    tree, _ = checkpoint.load(directory / "ckpt-000000000010.ckpt", {"x": np.zeros(1000)})
    assert tree["x"].shape == (1000,)


def failing_fsync(fd):
    raise OSError(errno.ENOSPC, "No space left on device")


def test_a_failing_write_names_the_path_and_keeps_the_previous_checkpoint_and_episodes(
        tmp_path, monkeypatch):
    run = RunWriter(config(), tmp_path)
    save_checkpoints(tmp_path, [10])
    store = EpisodeStore(tmp_path / "episodes")
    episode = read_episode(next((FIXTURE / "episodes").glob("*.mcap")))
    store.write(episode)
    with monkeypatch.context() as patch:
        patch.setattr(checkpoint.os, "fsync", failing_fsync)
        with pytest.raises(checkpoint.WriteError, match=r"cannot write .*ckpt-000000000020"
                                                        r"\.ckpt: No space left on device; "
                                                        "the file is as it was before"):
            save_checkpoints(tmp_path, [20])
        with pytest.raises(checkpoint.WriteError, match=r"cannot write .*episodes/.*\.mcap"):
            store.write(episode)
    assert [step for step, _ in run.checkpoints()] == [10]
    assert checkpoint.restore(tmp_path / "checkpoints", {"x": np.zeros(3, int)}).step == 10
    assert len(store.load()) == 1
    assert not [p for p in tmp_path.rglob("*.tmp")]
    run.unlock()


def test_train_reports_a_failing_write_in_one_line(old_run, capsys, monkeypatch):
    def failing_save(*args, **kwargs):
        raise checkpoint.WriteError("cannot write x.ckpt: No space left")

    monkeypatch.setattr(checkpoint, "save", failing_save)
    before = (old_run / "checkpoints" / CKPT).read_bytes()
    code, _, err = run_train(capsys, old_run, "train.steps=360")  # one more chunk, then save
    assert code == 1 and one_line_error(err) == "error: cannot write x.ckpt: No space left"
    assert (old_run / "checkpoints" / CKPT).read_bytes() == before


# --- bad values and flags --------------------------------------------------------------------

BAD_TRAIN_ARGS = {
    ("train.steps=-5",): "config key 'train.steps' got -5; valid: >= 1",
    ("train.steps=0",): "config key 'train.steps' got 0; valid: >= 1",
    ("train.batch=0",): "config key 'train.batch' got 0; valid: >= 1",
    ("train.batch=-3",): "config key 'train.batch' got -3; valid: >= 1",
    ("train.length=300",): "train.length=300 is longer than an episode of bbs_basic can be "
                           "(52 stored steps",
    ("train.eval_episodes=0",): "config key 'train.eval_episodes' got 0; valid: >= 1",
    ("train.prefill=-1",): "config key 'train.prefill' got -1; valid: >= 0",
    ("--seed", "-1"): "--seed -1: valid: an integer in [0, 1073741824]",
    ("train.steps=100",): "train.steps=100 ends before the run's first update, at env step "
                          "240 (prefill ends at env step 120 (train.prefill=100); the first "
                          "episodes end at env step 240 (51 agent steps with "
                          "env.time_limit=200, env.action_repeat=4, env.num_envs=1)), so it "
                          "would train nothing; the smallest train.steps that trains is 201",
    ("train.batch=100000",): "train.batch=100000 sequences of train.length=10 steps are more "
                             "steps than the replay ever holds (train.replay_capacity=10000); "
                             "valid: train.batch <= 1000",
    ("train.steps=600", "train.steps=800"): "config key 'train.steps' is given twice "
                                            "('train.steps=600' and 'train.steps=800')",
    ("train.steps=1e5",): "config key 'train.steps' wants an integer, got '1e5' (a float's "
                          "notation); write 100000",
    ("wm.lr=inf",): "config key 'wm.lr' got inf, which is not a finite number; valid: > 0",
    ("wm.kl_scale=nan",): "config key 'wm.kl_scale' got nan, which is not a finite number",
    ("--logdir", ""): "--logdir '' is empty; give a directory, or leave --logdir out",
}


@pytest.mark.parametrize("args", BAD_TRAIN_ARGS)
def test_a_bad_value_is_one_line_naming_it_and_nothing_is_written(args, tmp_path, capsys):
    code, _, err = run_train(capsys, tmp_path / "run", *args)
    assert code == 2 and BAD_TRAIN_ARGS[args] in one_line_error(err)
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("task", example_tasks())
@pytest.mark.parametrize("model", one_model_per_agent())
def test_the_debug_size_trains_within_its_steps_on_every_family(task, model):
    actions = family_of(task).actions
    if actions not in agent_entry(model).actions:
        pytest.skip(f"{model} does not act in {actions} action spaces")
    config = make_config(task, model, "debug")
    if family_of(task).on_device:
        first = DeviceProgram(config, make_device_task(config.env)).first_update()
    else:
        first = first_update(config)
    assert first.smallest_steps <= config.train.steps, first


def test_a_train_every_longer_than_a_device_episode_is_one_line(tmp_path, capsys):
    code = train.main(["--task", "mjx_cartpole_swingup", "--size", "debug", "--logdir",
                       str(tmp_path / "run"), "train.train_every=101"])
    _, err = capsys.readouterr()
    assert code == 2 and ("train.train_every=101 is longer than an episode of "
                          "mjx_cartpole_swingup (100 agent steps)") in one_line_error(err)
    assert not (tmp_path / "run").exists()


def test_a_truncated_config_json_is_an_error_naming_the_file(old_run, capsys):
    path = old_run / "config.json"
    path.write_text(path.read_text()[:100])
    message = f"{path} is damaged (not JSON: "
    code, _, err = run_train(capsys, old_run)
    assert code == 2 and message in one_line_error(err) and "--restart" in err
    assert evaluate.main([str(old_run)]) == 2
    assert message in one_line_error(capsys.readouterr().err)
    with pytest.raises(ConfigError, match="is damaged"):
        vsgjax.load(old_run)


def test_evaluate_flags_are_checked_before_running(old_run, tmp_path, capsys):
    cases = {("--episodes", "0"): "--episodes 0: valid: an integer >= 1",
             ("--seed", "-2"): "--seed -2: valid: an integer in",
             ("--output", str(tmp_path)): f"--output {tmp_path} is a directory",
             ("--output", str(old_run / "config.json" / "x.jsonl")): (
                 f"--output's directory {old_run / 'config.json'} is a file")}
    for args, message in cases.items():
        assert evaluate.main([str(old_run), *args]) == 2
        assert message in one_line_error(capsys.readouterr().err), args


def test_launch_root_and_report_out_that_are_files_are_one_line_errors(tmp_path, capsys):
    file = tmp_path / "file"
    file.write_text("x")
    assert launch.main(["bbs_basic", "--size", "debug", "--root", str(file),
                        "--backend", "print"]) == 2
    assert f"--root {file} is a file" in one_line_error(capsys.readouterr().err)
    assert report.main(["bbs_basic", "--size", "debug", "--root", str(tmp_path),
                        "--out", str(file)]) == 2
    assert f"--out {file} is a file" in one_line_error(capsys.readouterr().err)
    assert file.read_text() == "x"


def test_bbs_make_refuses_to_override_its_variant():
    with pytest.raises(ValueError, match=r"bbs.make\('bbs_basic', num_distractors=2\): variant "
                                         r"bbs_basic has num_distractors=0; valid: that value"):
        bbs.make("bbs_basic", num_distractors=2)
    assert bbs.make("bbs_basic_d2", num_distractors=2, time_limit=10).num_distractors == 2
