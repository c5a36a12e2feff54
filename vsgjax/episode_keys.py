"""The names of observation and episode entries, shared by the model, the envs, the data path
and the loop (see docs/replay-and-checkpoints.md for the episode format)."""

import numpy as np

IMAGE_KEY = "image"  # uint8 pixels [H, W, C]
VECTOR_KEY = "vector"  # the flat float32 observation of an MJX task [D]
IMAGE_DTYPE, VECTOR_DTYPE = np.dtype(np.uint8), np.dtype(np.float32)

# What an episode (and a sequence batch) holds besides its observation keys: no observation
# may take these names. ``action`` t led to observation t (zeros at t = 0).
NON_OBS_KEYS = ("action", "reward", "is_first", "is_terminal")
STEP_KEYS = ("reward", "is_first", "is_terminal")  # recorded per step with the observation
STREAM_KEYS = (*STEP_KEYS, "is_last")  # a collection chunk's stream besides the actions
EPISODE_DTYPES = {  # key -> (dtype, ndim including time) of the keys every episode has
    "action": (np.dtype(np.float32), 2),
    "reward": (np.dtype(np.float32), 1),
    "is_first": (np.dtype(bool), 1),
    "is_terminal": (np.dtype(bool), 1),
}
