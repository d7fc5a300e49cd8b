"""A user's posture law: pure integral levelling with anti-windup, while the built-in gait, terrain
adaptation and inverse kinematics stay as they are.

    PYTHONPATH=examples testbed run --controller posture --estimator ekf --set posture.law=my_posture_law:IntegralLevelling

The measured tilt is what remains after the correction, so the correction must accumulate to
remove a steady tilt (a slope, a step): an integral law. It holds while a leg is out of reach.
"""

import math

from testbed import PostureLaw

KI = 10.0                       # 1/s: rad of correction per second per rad of tilt
HEIGHT_KI = 3.0                 # 1/s: m of correction per second per m of height error
MAX_TILT = math.radians(10.0)   # rad
MAX_HEIGHT = 0.03               # m


class IntegralLevelling(PostureLaw):
    def __init__(self):
        self.last_t = None
        self.roll = self.pitch = self.height = 0.0

    def update(self, t, measurement, estimate, limited):
        dt = 0.0 if self.last_t is None else t - self.last_t
        self.last_t = t
        if not limited:
            self.roll = _clamp(self.roll - KI * dt * measurement.roll, MAX_TILT)
            self.pitch = _clamp(self.pitch - KI * dt * measurement.pitch, MAX_TILT)
            if measurement.height_error is not None:
                self.height = _clamp(self.height - HEIGHT_KI * dt * measurement.height_error, MAX_HEIGHT)
        return self.roll, self.pitch, self.height


def _clamp(value, limit):
    return max(-limit, min(limit, value))
