"""The motion of a real control (LinuxCNC 2.9's planner) running a 5-axis program as
written: the runs that turn the table crawl, the ball keeps to the sphere, and a plan
read with ``--controller linuxcnc`` takes that motion as its trajectory."""

from __future__ import annotations

import numpy as np
import pytest

from sdit_path.plan.files import load_plan
from sdit_path.plan.control_motion import control_samples, run_table


@pytest.mark.slow
def test_a_five_axis_program_runs_as_the_control_runs_it(five_axis_plan):
    plan = load_plan(five_axis_plan)
    program = plan.program_names[-1]  # the top layer: the table turns under the ball
    motion = control_samples(plan, program)
    planned = plan.trajectory(program)
    runs = run_table(planned, motion)
    assert len(runs) == 22
    ratios = np.array([r["control_s"] / r["planned_s"] for r in runs])
    # the runs that turn C take about twice their planned time (G93 blocks that move a
    # rotary axis are never blended), the meridian transits about theirs
    assert (ratios > 1.6).sum() == 12 and (np.abs(ratios - 1) < 0.02).sum() == 10
    # the joints move linearly between vertices on the sphere: the ball keeps to it
    pivot = np.asarray(plan.config.ballbar.pivot_mm)
    dev_um = (np.linalg.norm(motion.ball_mm - pivot, axis=1)
              - plan.config.ballbar.bar_length_mm) * 1e3
    assert np.abs(dev_um).max() < 0.2
    # every sample carries a segment of the plan, in the plan's order
    assert set(motion.segment) <= set(planned.segment)
    # read with --controller linuxcnc, the plan's trajectory is that motion
    lc = plan.for_controller("linuxcnc")
    assert lc.control_motion and not plan.control_motion
    assert lc.trajectory(program).t_s[-1] == pytest.approx(motion.t_s[-1])
    assert plan.trajectory(program).t_s[-1] == pytest.approx(planned.t_s[-1])
