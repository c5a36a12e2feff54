"""The run directory: its file names, and writing and reading them (one seed, one directory).

    config.json          the resolved config (only ``vsgjax.config.RESUMABLE_KEYS`` may change;
                         rebuilt from the newest checkpoint when it is missing)
    metrics.jsonl        train/episode/eval scalars, one line per log step (and TensorBoard)
    scores.jsonl         the learning curve ``{"task", "method", "seed", "xs", "ys", "wall_s",
                         "cpu_s"}`` (the run's wall and CPU seconds at each evaluation)
    eval_episodes.jsonl  one line per evaluation episode ``{"step", "episode", **info}``
    open_loop.jsonl      one line per evaluation of an agent with a world model: its open-loop
                         prediction errors per imagined step ``{"step", "obs_mse": [35],
                         "reward_mse": [35]}`` (:func:`open_loop_record`)
    checkpoints/         ``ckpt-<env step>.ckpt`` (:mod:`vsgjax.data.checkpoint`), each with
                         the config it was trained with; corrupt ones are moved to
                         ``checkpoints/corrupt/``, another run's to ``checkpoints/foreign/``
    episodes/            every finished training episode as MCAP (:mod:`vsgjax.data.replay`)
    videos/              eval and open-loop videos (image tasks)
    .lock                held by the training process (:mod:`vsgjax.loop.rundir_guard`)
    previous/<time>/     what ``--restart`` moved aside, or a killed attempt left (see
                         :class:`RunWriter`)

Training writes it (:class:`RunWriter`); evaluation, ``vsgjax.load`` and the experiments'
launcher and report read it (:class:`RunDir`).
"""

from __future__ import annotations

import dataclasses
import json
import math
from pathlib import Path

import numpy as np

from vsgjax.config import Config, ConfigError, config_changes, from_dict, to_dict
from vsgjax.data import checkpoint
from vsgjax.data.replay import EpisodeStore
from vsgjax.loop.logger import Logger, truncate_metrics
from vsgjax.loop.rundir_guard import (
    FOREIGN_DIR,
    RunDirError,
    RunLock,
    Survey,
    move_aside,
    remove_interrupted_writes,
    restart_hint,
    set_aside,
    set_aside_corrupt,
    survey_checkpoints,
)
from vsgjax.loop.schedule import Counters
from vsgjax.outdir import make_output_dir
from vsgjax.registry.agents import agent_entry

CONFIG_FILE = "config.json"
METRICS_FILE = "metrics.jsonl"
SCORES_FILE = "scores.jsonl"
EVAL_EPISODES_FILE = "eval_episodes.jsonl"
OPEN_LOOP_FILE = "open_loop.jsonl"
CHECKPOINTS_DIR = "checkpoints"
EPISODES_DIR = "episodes"
VIDEOS_DIR = "videos"
KEEP_CHECKPOINTS = 3
OPEN_LOOP_STEPS = (5, 15, 35)  # imagined steps whose errors the eval record holds as scalars
OPEN_LOOP_ERRORS = ("obs_mse", "reward_mse")
# the ``method`` of scores.jsonl: the names of the paper's curves

def json_safe(record: dict) -> dict:
    """NaN/inf (e.g. 'never visited' discovery metrics) become null in JSON files."""
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in record.items()}


def episode_records(infos: list[dict], step: int) -> list[dict]:
    """One JSON-able record per evaluation episode: ``{"step", "episode", **info}``."""
    return [json_safe({"step": step, "episode": index, **info})
            for index, info in enumerate(infos)]


def open_loop_record(step: int, errors: dict) -> dict:
    """The ``open_loop.jsonl`` line of one evaluation: ``{"step": env step, "obs_mse": [H],
    "reward_mse": [H]}``, entry ``k - 1`` the error at imagined step ``k`` (H = 35, fewer for
    short episodes: :func:`vsgjax.agents.dreamer.open_loop.shortened`); non-finite values
    are null."""
    record: dict = {"step": int(step)}
    for name in OPEN_LOOP_ERRORS:
        values = [float(v) for v in np.asarray(errors[name], np.float64).reshape(-1)]
        record[name] = [v if math.isfinite(v) else None for v in values]
    return record


def open_loop_scalars(errors: dict) -> dict[str, float]:
    """The eval record's scalars of an evaluation's open-loop errors: ``open_loop/obs_mse_5``,
    ``..._15``, ``..._35`` and the same of ``reward_mse`` (the imagined steps of
    ``OPEN_LOOP_STEPS`` that the errors reach)."""
    scalars = {}
    for name in OPEN_LOOP_ERRORS:
        values = np.asarray(errors[name], np.float64).reshape(-1)
        scalars.update({f"open_loop/{name}_{k}": float(values[k - 1])
                        for k in OPEN_LOOP_STEPS if k <= len(values)})
    return scalars


class RunDir:
    """Reading a run directory: paths, config, checkpoints, episode files, scores."""

    def __init__(self, logdir: str | Path):
        self.logdir = Path(logdir)
        self.ckpt_dir = self.logdir / CHECKPOINTS_DIR
        self.episodes_dir = self.logdir / EPISODES_DIR

    def path(self, name: str) -> Path:
        return self.logdir / name

    def has_config(self) -> bool:
        return self.path(CONFIG_FILE).exists()

    def read_config_dict(self) -> dict:
        path = self.path(CONFIG_FILE)
        try:
            return json.loads(path.read_text())
        except json.JSONDecodeError as error:
            raise ConfigError(f"{path} is damaged (not JSON: {error}); restore it from a "
                              "copy, or start the run over with `python -m vsgjax.train "
                              "--restart` (which moves the old run aside)") from None

    def load_config(self) -> Config:
        if not self.has_config():
            raise FileNotFoundError(f"{self.path(CONFIG_FILE)} not found: is {self.logdir} a "
                                    "training log directory?")
        return from_dict(self.read_config_dict())

    def checkpoints(self) -> list[tuple[int, Path]]:
        """``(env step, path)`` of every checkpoint, oldest first."""
        return checkpoint.list_checkpoints(self.ckpt_dir)

    def episode_paths(self) -> list[Path]:
        """The episode files, oldest first."""
        return sorted(self.episodes_dir.glob("*.mcap")) if self.episodes_dir.is_dir() else []

    def read_scores(self) -> dict | None:
        path = self.path(SCORES_FILE)
        return json.loads(path.read_text()) if path.exists() else None

    def evaluated_without_checkpoint(self) -> int | None:
        """The env step of the newest evaluation of a run that has no checkpoint to resume
        from (committed results, a copied directory, a deleted ``checkpoints/``); None when it
        has a checkpoint or no readable evaluation. Training there would start the run over
        and replace its results."""
        if self.checkpoints():
            return None
        try:
            scores = self.read_scores()
        except (OSError, ValueError):
            return None
        xs = scores.get("xs") if isinstance(scores, dict) else None
        return int(xs[-1]) if xs else None


class RunWriter(RunDir):
    """Writing one seed's run directory during training (either loop): config, logs, scores,
    eval records, episode files, checkpoints."""

    replay_steps = 0  # steps in the seed's replay (the trainer keeps it current)

    def __init__(self, config: Config, logdir: Path, *, restart: bool = False,
                 prepare: bool = True):
        """Lock the directory and check, reading only, that it holds this config's run (or,
        with ``restart``, nothing to check): every refusal comes here, before anything in it
        is moved or written. Then (``prepare``, else the caller calls :meth:`prepare`) tidy
        it for the run."""
        super().__init__(logdir)
        self.config, self.seed, self.restart = config, config.train.seed, restart
        make_output_dir(self.logdir, "log directory")
        self.lock = RunLock(self.logdir)
        try:
            self.survey = None if restart else self._check()
        except BaseException:
            self.lock.unlock()
            raise
        self.moved_to = self.attempt_moved_to = None
        self.foreign_moved: list[tuple[Path, Path, str]] = []  # (checkpoint, moved to, why)
        self.logger: Logger | None = None  # opened by open_logs
        self.scores: dict = {"xs": [], "ys": []}
        self.episodes = 0
        self.checkpoint_path: Path | None = None
        self.episodes_moved_to: Path | None = None  # by load: those after the checkpoint
        self.window: list[dict] = []  # metrics of the updates since the last log
        self.window_episodes: list[dict] = []
        if prepare:
            self.prepare()

    @property
    def config_from(self) -> Path | None:
        """The checkpoint the run's config was rebuilt from (``config.json`` was missing)."""
        return self.survey.config_from if self.survey else None

    def prepare(self) -> None:
        """(``restart``) move the old contents aside, or set the corrupt checkpoints and
        those of another run aside; remove what killed writes left; a first attempt killed
        before its first checkpoint and evaluation is moved aside."""
        try:
            if self.restart:
                self.moved_to = move_aside(self.logdir)
            else:
                set_aside_corrupt(self.ckpt_dir, self.survey.corrupt)
                self.set_aside_foreign(self.survey.foreign)
            remove_interrupted_writes(self.logdir, self.ckpt_dir, self.episodes_dir,
                                      self.path(VIDEOS_DIR))
            self.attempt_moved_to = None if self.checkpoints() else self._move_killed_attempt()
            self.store = EpisodeStore(self.episodes_dir)
        except BaseException:
            self.lock.unlock()
            raise

    def set_aside_foreign(self, foreign: dict[Path, str]) -> None:
        """Move another run's checkpoints (path -> why) to ``checkpoints/foreign/``."""
        moved = set_aside(self.ckpt_dir, FOREIGN_DIR, foreign)
        self.foreign_moved += [(path, target, foreign[path]) for path, target in moved.items()]

    def _check(self) -> Survey:
        """Every refusal of a directory that holds another run, or no run to resume: corrupt
        checkpoints only, the checkpoints of another run only, a config that cannot be told,
        a different config, evaluations without a checkpoint. Reads only."""
        survey = survey_checkpoints(self.logdir, self.ckpt_dir, self._saved_config())
        if survey.config is not None and (self.checkpoints() or self.episode_paths()):
            changed = config_changes(survey.config, to_dict(self.config))
            if changed:
                where = (f" (its config as {survey.config_from.name} holds it: config.json is "
                         "missing)" if survey.config_from else "")
                raise ConfigError(f"{self.logdir} holds a run with a different config ("
                                  + "; ".join(changed) + f"){where}; {restart_hint(self.logdir)}")
        self._check_resumable()
        return survey

    def _saved_config(self) -> dict | None:
        """``config.json`` when the directory holds data to check it against, else None."""
        if not self.has_config() or not (self.checkpoints() or self.episode_paths()):
            return None
        return self.read_config_dict()

    def _check_resumable(self) -> None:
        """Training over evaluations that no checkpoint can resume would start the run over
        and replace its results, so it is refused."""
        evaluated = self.evaluated_without_checkpoint()
        if evaluated is not None:
            where = ("checkpoints/ is empty" if self.ckpt_dir.is_dir()
                     else "there is no checkpoints/")
            raise RunDirError(f"{self.logdir} holds the evaluations of a run to env step "
                              f"{evaluated} but no checkpoint to resume it from ({where}); "
                              f"nothing was changed; {restart_hint(self.logdir)}")

    def _move_killed_attempt(self) -> Path | None:
        """What an attempt killed before its first checkpoint and evaluation wrote (episodes,
        log lines, videos) goes to ``previous/<time>/``, so that the new run starts as an
        uninterrupted one would; returns where (None when it left no data)."""
        logged = self.path(METRICS_FILE).exists() and self.path(METRICS_FILE).stat().st_size
        videos = self.path(VIDEOS_DIR)
        if not (self.episode_paths() or logged or (videos.is_dir() and any(videos.iterdir()))):
            return None
        return move_aside(self.logdir)

    def load(self, restored: checkpoint.Checkpoint) -> None:
        """Take the run's scores and episode count from its checkpoint; the episode files
        written after it (by a killed run) go to ``previous/<time>/episodes/``, so the
        resumed run's replay holds what the checkpointed one had."""
        self.scores = restored.meta["scores"]
        counters = restored.meta["counters"]
        self.episodes = counters.get("episodes", 0)
        self.checkpoint_path = restored.path
        if "episodes" in counters:  # older checkpoints did not count them
            self.episodes_moved_to = move_aside(self.logdir,
                                                self.episode_paths()[self.episodes:])

    def open_logs(self, env_steps: int) -> None:
        """Write config and scores, open the logs (dropping records after ``env_steps``)."""
        checkpoint.atomic_write(self.path(CONFIG_FILE),
                                json.dumps(to_dict(self.config), indent=2).encode())
        # Records an interrupted run wrote after the restored step are dropped.
        self.logger = Logger(self.logdir, resume_step=env_steps, metrics_file=METRICS_FILE,
                             video_dir=VIDEOS_DIR)
        truncate_metrics(self.path(EVAL_EPISODES_FILE), env_steps)
        truncate_metrics(self.path(OPEN_LOOP_FILE), env_steps)
        self.write_scores()

    def write_scores(self) -> None:
        method = agent_entry(self.config.agent).display
        record = {"task": self.config.env.task, "method": method,
                  "seed": str(self.seed), **self.scores}
        checkpoint.atomic_write(self.path(SCORES_FILE), (json.dumps(record) + "\n").encode())

    def on_episode(self, episode: dict, info: dict, env_steps: int, *,
                   numbered: bool = False) -> None:
        """Write a finished training episode and log its ``info``. ``numbered``: name its file
        by the run's episode count (:meth:`EpisodeStore.write`), for a loop whose resume
        replays exactly the episodes written after its checkpoint, so that each rewrite
        replaces its file."""
        self.store.write(episode, number=self.episodes if numbered else None)
        self.episodes += 1
        self.window_episodes.append(info)
        self.logger.scalars(env_steps, info, prefix="episode")

    def log(self, env_steps: int, shared: dict) -> dict:
        """Write the train record of this log interval (means over its updates); returns it."""
        record = {**shared, "episodes": self.episodes, "replay_steps": self.replay_steps}
        if self.window:
            record.update({k: float(np.mean([m[k] for m in self.window])) for k in self.window[0]})
        if self.window_episodes:
            record["return"] = float(np.mean([e["return"] for e in self.window_episodes]))
        self.logger.scalars(env_steps, record, prefix="train")
        self.window, self.window_episodes = [], []
        return record

    def record_eval(self, step: int, infos: list[dict], summary: dict,
                    open_loop: dict | None = None) -> None:
        """One evaluation: its ``eval/*`` record (with the ``open_loop/*`` scalars of
        ``open_loop``, the agent's open-loop errors, when given), its episodes, its
        ``open_loop.jsonl`` line, and the scores."""
        scalars = dict(summary)
        if open_loop is not None:
            scalars.update(open_loop_scalars(open_loop))
        self.logger.scalars(step, scalars, prefix="eval")
        with open(self.path(EVAL_EPISODES_FILE), "a") as file:
            for record in episode_records(infos, step):
                file.write(json.dumps(record) + "\n")
        if open_loop is not None:
            with open(self.path(OPEN_LOOP_FILE), "a") as file:
                file.write(json.dumps(open_loop_record(step, open_loop)) + "\n")
        self.scores["xs"].append(float(step))
        self.scores["ys"].append(summary["return"])
        for clock in ("wall_s", "cpu_s"):
            self.scores.setdefault(clock, []).append(summary[clock])
        self.write_scores()

    def save(self, env_steps: int, counters: Counters, tree: dict, **meta) -> None:
        """A checkpoint of ``tree``; its meta holds the counters, the scores and the config
        the run was trained with (which a resume must match)."""
        meta = {"counters": {**dataclasses.asdict(counters), "episodes": self.episodes},
                "scores": self.scores, "config": to_dict(self.config), **meta}
        self.checkpoint_path = checkpoint.save(self.ckpt_dir, env_steps, tree, meta,
                                               keep=KEEP_CHECKPOINTS)

    def last_good_checkpoint(self) -> str:
        last = checkpoint.latest(self.ckpt_dir)
        return f"the last good checkpoint is {last}" if last else "no checkpoint was saved yet"

    def unlock(self) -> None:
        """Unlock the directory (another process may train into it)."""
        self.lock.unlock()

    def close(self) -> None:
        if self.logger is not None:
            self.logger.close()
        self.unlock()
