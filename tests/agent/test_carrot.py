"""The carrot a path is flown by (`swarm.agent.flight.carried_lead`): pure geometry; the flights are in
`test_fly_path.py`."""

from __future__ import annotations

import numpy as np
import pytest

from swarm.agent.flight import carried_lead


def test_a_new_carrot_keeps_the_old_ones_lead_in_the_new_direction() -> None:
    here = (0.0, 0.0, 1.5)
    assert carried_lead(here, None, (5.0, 0.0, 1.5)) == 0.0
    assert carried_lead(here, (0.8, 0.0, 1.5), (5.0, 0.0, 1.5)) == pytest.approx(0.8)  # straight on
    assert carried_lead(here, (0.8, 0.0, 1.5), (5.0, 5.0, 1.5)) == pytest.approx(0.8 / np.sqrt(2))  # 45 degrees
    assert carried_lead(here, (0.8, 0.0, 1.5), (-5.0, 0.0, 1.5)) == 0.0  # a U-turn starts at the drone
    assert carried_lead(here, (0.8, 0.0, 1.5), (0.3, 0.0, 1.5)) == pytest.approx(0.3)  # within the segment
    assert carried_lead(here, (2.0, 0.0, 1.5), (5.0, 0.0, 1.5)) == pytest.approx(1.0)  # within the look-ahead
