"""Issue 30: a person steps onto the path ahead of the moving robot (R37), the path watch against
distances alone (``depthguard.evaluation.onto_path``, ``depthguard reproduce path-watch``).

Truth: the simulator's own geometry — the robot's collision capsules (points every 1 cm along each
axis) against the scripted person's primitives (``true_distance``), at every control cycle and along
the planned path. Not the monitor's map, distances or verdicts.
"""

from __future__ import annotations

import numpy as np
import pytest

from depthguard.evaluation.onto_path import OntoPath, PersonTruth, _first_contact, _interp, compare
from depthguard.sim import load_cell


def test_the_scenario_puts_the_person_onto_the_path_ahead_and_takes_them_off():
    """The scenario itself, against the truth: off the path before and after, on a later part of it
    during the hold (first contact well ahead of where the robot is when the hand arrives)."""
    rig = load_cell("ur3-cell").rig
    s = OntoPath()
    stamps, Q = s.path(rig)
    person = s.person(rig)
    truth = PersonTruth(rig.robot, Q[0])
    before, during, after = person.primitives(0.0), person.primitives(s.t_hold[0] + 0.5), person.primitives(s.t_gone)
    assert _first_contact(truth, before, stamps, Q, 0.0) == np.inf
    assert _first_contact(truth, after, stamps, Q, 0.0) == np.inf
    hit = _first_contact(truth, during, stamps, Q, 0.0)
    assert s.t_hold[0] + 2.0 < hit < stamps[-1]          # ahead of the robot (path time = time while unhindered)
    assert truth(_interp(stamps, Q, s.t_hold[0]), during) > 0.0


@pytest.mark.slow
def test_the_path_watch_stops_short_of_the_person_and_resumes_by_itself():
    """Both runs of the scenario (the monitor at 100 Hz to keep the test short; 7 s simulated):
    with the path watch the robot stops before the first path time at which it would touch the
    person, its minimum true separation is larger than with distances alone (which run into the
    hand), and once the person has left it moves on by itself."""
    s = OntoPath(control_hz=100.0, duration=7.0)
    dist, watch = compare(s)
    assert dist["run"] == "distances" and watch["run"] == "path watch"
    assert watch["stopped"] and watch["short"] and not watch["contact"], watch
    assert watch["tau_stop"] < watch["tau_contact"] and watch["sep_at_stop_m"] > 0.0
    assert watch["min_sep_m"] > dist["min_sep_m"] + 0.03, (watch["min_sep_m"], dist["min_sep_m"])
    # resumes by itself: after the person starts to leave, within half a second of the rest of the
    # path being truly free, and goes on along the path
    assert watch["t_resume"] is not None and watch["t_resume"] > s.t_hold[1], watch
    assert watch["left_s"] is not None and watch["t_resume"] - watch["left_s"] <= 0.5, watch
    assert watch["progress"] > watch["tau_stop"] / s.path_s + 0.2, watch
