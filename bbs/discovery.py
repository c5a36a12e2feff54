"""The paper's discovery metrics, computed per episode.

An object counts as *visited* at the first agent step whose observation shows it completely
inside the view box (every vertex inside; step 0 is the reset observation). At the end of an
episode ``summary`` reports:

* ``episode_length``: agent steps taken;
* ``first_visit``: tuple with each object's first-visit step, -1 if never visited;
* ``mean_first_visit``: mean over visited objects (NaN if none was visited);
* ``never_visited``: percentage of objects never visited;
* ``visited_not_scored``: percentage of visited objects that were not scored (NaN if none
  was visited);
* ``scored``: number of objects scored.
"""

import math

import numpy as np

NOT_VISITED = -1


class DiscoveryTracker:
    def __init__(self, num_objects: int):
        self.first_visit = np.full(num_objects, NOT_VISITED, dtype=np.int64)

    def observe(self, step: int, visible_ids) -> None:
        """Record that the objects with indices ``visible_ids`` are fully in view at ``step``."""
        for i in visible_ids:
            if self.first_visit[i] == NOT_VISITED:
                self.first_visit[i] = step

    def summary(self, episode_length: int, scored: np.ndarray) -> dict:
        visited = self.first_visit != NOT_VISITED
        num_objects, num_visited = len(visited), int(visited.sum())
        nan = math.nan
        return {
            "episode_length": episode_length,
            "first_visit": tuple(int(t) for t in self.first_visit),
            "mean_first_visit": float(self.first_visit[visited].mean()) if num_visited else nan,
            "never_visited": 100.0 * (num_objects - num_visited) / num_objects,
            "visited_not_scored": (
                100.0 * float((visited & ~scored).sum()) / num_visited if num_visited else nan
            ),
            "scored": int(scored.sum()),
        }
