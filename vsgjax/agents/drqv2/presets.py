"""DrQ-v2's presets: the authors' hyperparameters per preset column (``COLUMN``), the sizes
(``SIZE``) and the authors' per-task overrides (``TASK``, ``TASK_ONLY``, ``DIFFICULTY``), as
dotted config keys. Pure data (facebookresearch/drqv2 ``cfgs/config.yaml`` and ``cfgs/task/``);
:func:`vsgjax.config.make_config` applies ``COLUMN`` and ``SIZE``. ``COLUMN`` holds the preset
columns DrQ-v2 trains on (continuous actions); make_config refuses a task of another column.

Units: ``train.steps``, ``train.prefill`` and ``train.eval_every`` count env steps (frames, the
authors' ``*_frames``); ``train.train_every`` (their ``update_every_steps``) and
``drq.std_steps`` (the duration of their ``stddev_schedule``) count agent steps.

The authors' task difficulty (``cfgs/task/{easy,medium,hard}.yaml``)::

    easy    num_train_frames 1_100_000   stddev_schedule linear(1.0, 0.1, 100_000)
            cartpole_balance, cartpole_balance_sparse, cartpole_swingup, cup_catch,
            finger_spin, hopper_stand, pendulum_swingup, walker_stand, walker_walk
    medium  num_train_frames 3_100_000   stddev_schedule linear(1.0, 0.1, 500_000)
            acrobot_swingup, cartpole_swingup_sparse, cheetah_run, finger_turn_easy,
            finger_turn_hard, hopper_hop, quadruped_run, quadruped_walk, reach_duplo,
            reacher_easy, reacher_hard, walker_run
    hard    num_train_frames 30_100_000  stddev_schedule linear(1.0, 0.1, 2_000_000)
            humanoid_run, humanoid_stand, humanoid_walk

The columns take ``medium`` (the default task of ``cfgs/config.yaml``, quadruped_walk, is
medium); ``DIFFICULTY`` and ``TASK_DIFFICULTY`` hold the other two as data.
"""

# cfgs/config.yaml (agent: DrQV2Agent) with the medium task file.
_AUTHORS = {
    "drq.feature_dim": 50, "drq.hidden": 1024, "drq.cnn_depth": 32, "drq.frame_stack": 3,
    "drq.nstep": 3, "drq.gamma": 0.99, "drq.tau": 0.01, "drq.lr": 1e-4,
    "drq.std_start": 1.0, "drq.std_end": 0.1, "drq.std_steps": 500_000, "drq.std_clip": 0.3,
    "drq.shift_pad": 4,  # RandomShiftsAug(pad=4) in DrQV2Agent.__init__
    "train.batch": 256, "train.train_every": 2, "train.prefill": 4000,
    "train.replay_capacity": 1_000_000,
    "train.steps": 3_100_000,  # medium's num_train_frames (easy 1_100_000, hard 30_100_000)
    "train.eval_every": 10_000, "train.eval_episodes": 10, "train.pretrain": 0,
    "train.length": 4,  # unused by DrQ-v2 (agent.replay sets the windows): nstep + 1
}

COLUMN = {
    "dmc": {
        "env.action_repeat": 2, "env.time_limit": 1000, "env.image_size": 84,
        **_AUTHORS,
    },
    # BringBackShapes with its own env settings (the paper's BBS observation: 64x64, action
    # repeat 4, 3000 env steps) and its benchmark protocol (the bbs column of the other agents:
    # 2.5M env steps, evaluation every 50k); the agent's hyperparameters are the authors'.
    "bbs": {
        **_AUTHORS,
        "env.action_repeat": 4, "env.time_limit": 3000, "env.image_size": 64,
        "train.steps": 2_500_000, "train.eval_every": 50_000,
    },
}

SIZE = {
    "paper": {},
    # Pixels on a CPU: 100k agent steps, the std at its floor after half of them (the
    # authors' easy tasks: after a fifth, medium: a third).
    "small": {
        "drq.hidden": 256, "drq.feature_dim": 50, "drq.std_steps": 50_000,
        "train.batch": 64, "train.replay_capacity": 100_000, "train.steps": 200_000,
        "train.eval_every": 10_000, "train.eval_episodes": 2, "train.log_every": 2000,
    },
    # Vector observations only (mjx_ tasks), 100k env steps on a 2-core CPU: the authors'
    # update rule at a quarter of the width; the std reaches its floor halfway through the run's
    # 50k agent steps (the authors' medium tasks: a third of the run).
    "cpu": {
        "drq.hidden": 256, "drq.std_steps": 25_000,
        "env.num_envs": 1, "train.batch": 256, "train.train_every": 2, "train.prefill": 4000,
        "train.steps": 100_000, "train.eval_every": 4000, "train.eval_episodes": 4,
        "train.log_every": 2000, "train.replay_capacity": 200_000,
    },
    "debug": {  # episodes of 200 env steps, as the Dreamer family's debug size
        "env.time_limit": 200,
        "drq.hidden": 32, "drq.feature_dim": 8, "drq.cnn_depth": 4, "drq.std_steps": 1000,
        "train.batch": 8, "train.prefill": 100, "train.steps": 400, "train.eval_every": 200,
        "train.eval_episodes": 1, "train.log_every": 50, "train.ckpt_every": 5,
        "train.video_every": 200, "train.replay_capacity": 10_000,
    },
}

# The authors' per-task overrides that hold for every task of a DMC domain in cfgs/task/
# (walker_{stand,walk,run}.yaml: nstep 1, batch_size 512; humanoid_{stand,walk,run}.yaml:
# lr 8e-5, feature_dim 100).
TASK = {
    "walker": {"drq.nstep": 1, "train.batch": 512},
    "humanoid": {"drq.lr": 8e-5, "drq.feature_dim": 100},
}

# Overrides of one task only (quadruped_run.yaml: replay_buffer_size 100000; not quadruped_walk).
TASK_ONLY = {
    "quadruped_run": {"train.replay_capacity": 100_000},
}

# cfgs/task/{easy,medium,hard}.yaml and which task files take which.
DIFFICULTY = {
    "easy": {"drq.std_steps": 100_000, "train.steps": 1_100_000},
    "medium": {"drq.std_steps": 500_000, "train.steps": 3_100_000},
    "hard": {"drq.std_steps": 2_000_000, "train.steps": 30_100_000},
}
TASK_DIFFICULTY = {
    **dict.fromkeys(("cartpole_balance", "cartpole_balance_sparse", "cartpole_swingup",
                     "cup_catch", "finger_spin", "hopper_stand", "pendulum_swingup",
                     "walker_stand", "walker_walk"), "easy"),
    **dict.fromkeys(("acrobot_swingup", "cartpole_swingup_sparse", "cheetah_run",
                     "finger_turn_easy", "finger_turn_hard", "hopper_hop", "quadruped_run",
                     "quadruped_walk", "reach_duplo", "reacher_easy", "reacher_hard",
                     "walker_run"), "medium"),
    **dict.fromkeys(("humanoid_run", "humanoid_stand", "humanoid_walk"), "hard"),
}


def for_task(name: str) -> dict:
    """The authors' overrides of a DeepMind Control task (``walker_walk``, the task name after
    its family's prefix; ``ball_in_cup_catch`` is their ``cup_catch``): its difficulty's
    schedule and length, then its domain's and its own file's overrides; {} for other tasks."""
    name = name.replace("ball_in_cup_", "cup_")
    layer = dict(DIFFICULTY.get(TASK_DIFFICULTY.get(name, ""), {}))
    layer.update(TASK.get(name.partition("_")[0], {}))
    layer.update(TASK_ONLY.get(name, {}))
    return layer
