"""A user's terrain: a washboard of low bars across the walking direction.

    PYTHONPATH=examples testbed run --terrain my_terrain:Washboard --gait tripod --controller posture --estimator ekf

Every terrain is a union of boxes (what DART and the compliant contact collide with) plus the
analytic height the metrics and the start placement ask for.
"""

import numpy as np

from testbed import Terrain
from testbed.world.terrain import BASE_DEPTH, Boxes

BAR_HEIGHT = 0.01       # m
BAR_WIDTH = 0.04        # m along x
BAR_SPACING = 0.25      # m between bar starts
FIRST_BAR = 0.3         # m, x of the first bar's start


class Washboard(Terrain):
    def __init__(self, config):
        x0, x1, y0, y1 = config.extent
        self.starts = np.arange(FIRST_BAR, x1 - BAR_WIDTH, BAR_SPACING)
        ground = _box(x0, x1, y0, y1, -BASE_DEPTH, 0.0)
        bars = [_box(x, x + BAR_WIDTH, y0, y1, 0.0, BAR_HEIGHT) for x in self.starts]
        boxes = [ground] + bars
        super().__init__(config, Boxes(np.array([b[0] for b in boxes]), np.array([b[1] for b in boxes]),
                                       np.repeat(np.eye(3)[None], len(boxes), axis=0)))

    def height(self, xy):
        x = np.atleast_2d(xy)[:, 0]
        on_bar = ((x[:, None] >= self.starts) & (x[:, None] < self.starts + BAR_WIDTH)).any(axis=1)
        return np.where(on_bar, BAR_HEIGHT, 0.0)


def _box(x0, x1, y0, y1, z0, z1):
    """(centre, half extents) of an axis-aligned box."""
    return np.array([(x0 + x1) / 2, (y0 + y1) / 2, (z0 + z1) / 2]), np.array([(x1 - x0) / 2, (y1 - y0) / 2, (z1 - z0) / 2])
