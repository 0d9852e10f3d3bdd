"""What analysis.txt says about a recording's timing: whose it is, and the runs whose
measured duration differs from the plan's beyond their uncertainty."""

from __future__ import annotations

from sdit_path.reports.analysis import _timing_lines


def test_runs_timed_by_the_recording_are_listed_where_they_differ_beyond_their_uncertainty():
    runs = [
        # 2 % off but within three standard uncertainties: not a finding
        {"from": "A-1>B-1", "to": "A-1>B-1", "planned_s": 4.76, "model_s": 4.69,
         "measured_s": 4.66, "std_s": 0.05, "told": True},
        # twice the planned time, well determined: listed with the planner's time
        {"from": "E1-1", "to": "E1-3", "planned_s": 6.33, "model_s": 12.45,
         "measured_s": 12.41, "std_s": 0.02, "told": True},
        # within 2 %: not listed
        {"from": "B-1>A-1", "to": "B-1>A-1", "planned_s": 4.76, "model_s": 4.69,
         "measured_s": 4.75, "std_s": 0.004, "told": True},
    ]
    lines = _timing_lines({"model": "recording", "from": "linuxcnc", "runs": runs})
    text = "\n".join(lines)
    assert "run by run" in lines[0] and "linuxcnc's motion" in lines[0] and "k=1" in lines[0]
    assert "2 of 3 runs within 2 %" in lines[0]
    assert len(lines) == 2
    assert "run E1-1..E1-3: 12.41 +- 0.02 s, planned 6.33 s (linuxcnc's planner: 12.45 s)" in text


def test_the_plans_timing_says_nothing_and_a_controls_motion_says_whose():
    assert _timing_lines({"model": "plan"}) == []
    lines = _timing_lines({"model": "linuxcnc", "runs": [
        {"from": "E1-1", "to": "E1-3", "planned_s": 6.33, "control_s": 12.45}]})
    assert "LinuxCNC 2.9's planner" in lines[0]
    assert lines[1].strip() == "run E1-1..E1-3: 12.45 s, planned 6.33 s"


def test_how_well_the_runs_are_placed_says_what_it_blurs():
    runs = [{"from": "E1-1", "to": "E1-3", "planned_s": 6.33, "measured_s": 6.33,
             "std_s": 0.01, "told": True}]
    coarse = _timing_lines({"model": "recording", "from": "plan", "placed_std_s": 0.016,
                            "runs": runs})
    fine = _timing_lines({"model": "recording", "from": "plan", "placed_std_s": 0.0008,
                          "runs": runs})
    assert "+- 16.0 ms" in coarse[-1] and "above 10 Hz" in coarse[-1]
    assert "+- 0.8 ms" in fine[-1] and "above 199 Hz" in fine[-1]
    # an older analysis.json without the figure: nothing made up
    assert not any("places the runs" in x for x in
                   _timing_lines({"model": "recording", "from": "plan", "runs": runs}))
