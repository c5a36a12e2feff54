"""The names of the files in a training run's log directory that the launcher and the report
read (``vsgjax.train`` writes them; see docs/training.md)."""

CONFIG_FILE = "config.json"  # the resolved config of the run
SCORES_FILE = "scores.jsonl"  # the learning curve, rewritten whole at every evaluation
EPISODES_FILE = "eval_episodes.jsonl"  # one line per evaluation episode
METRICS_FILE = "metrics.jsonl"  # the training metrics, one line per log step
CHECKPOINTS_DIR = "checkpoints"
