"""Walking in the physics: every gait keeps the centre of mass inside the support polygon on both
contact models (issue 3's static stability), with the touch-down confirmation and swing lead."""

import pytest

from testbed.runtime import config
from testbed.runtime.runner import run

SPEEDS = {"tripod": 0.1, "ripple": 0.06, "wave": 0.04}


@pytest.mark.parametrize("contact", ["compliant", "dart"])
@pytest.mark.parametrize("gait", list(SPEEDS))
def test_every_gait_keeps_a_positive_stability_margin(gait, contact):
    # The start-up (2.2 s), the 1 s ramp and one full cycle of the slowest gait at full speed.
    cfg = config.load(overrides={"run": {"gait": gait, "contact": contact, "duration": 5.0},
                                 "gait": {"speed": SPEEDS[gait]}})
    metrics = run(cfg).metrics
    assert not metrics["fell"]
    assert metrics["min_stability_margin_m"] is not None and metrics["min_stability_margin_m"] > 0.003
    assert metrics["distance_m"] > 0.8 * SPEEDS[gait] * (5.0 - cfg.startup_time - 0.5 * cfg.gait.start_ramp)
