"""FindClosest of the RRTs (aorrt.py, joint.py): the nearest node of a growing tree."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree


class Nearest:
    """Nearest nodes by key (a row of ``keys`` per node): a kd-tree (scipy cKDTree) over
    the nodes it was built on plus brute force over the newer ones; rebuilt when
    these exceed max(64, a quarter of the built ones), so the tree is at most that
    stale and a query stays exact."""

    def __init__(self, keys: np.ndarray):
        self.keys, self.kd, self.built = keys, None, 0

    def query(self, q: np.ndarray, n: int) -> np.ndarray:
        """Index of the nearest of the first ``n`` nodes for every row of ``q``."""
        if self.kd is None or n - self.built > max(64, self.built // 4):
            self.kd, self.built = cKDTree(self.keys[:n]), n
        d_kd, near = self.kd.query(q)
        if n > self.built:
            d_new = np.linalg.norm(q[:, None, :] - self.keys[None, self.built:n], axis=2)
            j = d_new.argmin(1)
            near = np.where(d_new[np.arange(len(q)), j] < d_kd, self.built + j, near)
        return near
