"""A trajectory re-timed run by run keeps its path and takes the times it is given."""

from __future__ import annotations

import numpy as np
import pytest

from sdit_path.timing.retime import Retiming, retime
from sdit_path.timing.trajectory import Samples


def _two_runs(period: float = 0.001) -> Samples:
    """Dwell 1 s, a run of 2 s along a circle arc, dwell 1 s, a run of 1 s back, dwell 1 s."""
    t = np.arange(0.0, 6.0 + period / 2, period)
    s = np.zeros_like(t)  # arc parameter, smooth ramps (1 - cos)
    a = (t >= 1) & (t < 3)
    s[a] = 0.5 * (1 - np.cos(np.pi * (t[a] - 1) / 2))
    s[(t >= 3) & (t < 4)] = 1.0
    b = (t >= 4) & (t < 5)
    s[b] = 1.0 - 0.5 * (1 - np.cos(np.pi * (t[b] - 4)))
    ang = 0.8 * s
    ball = np.column_stack([100 * np.cos(ang), 100 * np.sin(ang), np.zeros_like(t)])
    phase = np.where(a | b, "cruise", "dwell").astype(object)
    speed = np.r_[0.0, np.linalg.norm(np.diff(ball, axis=0), axis=1) / period]
    return Samples(t, ball, ball.copy(), np.full(len(t), "S1", dtype=object), phase, speed,
                   ("X", "Y", "Z"), ("mm", "mm", "mm"))


def test_a_retimed_trajectory_keeps_its_path_and_takes_the_given_times():
    src = _two_runs()
    # the first run takes twice as long, the dwell between 0.02 s more, the second run
    # 0.9 of its time
    r = Retiming((0.0, 1.0, 3.0, 4.0, 5.0, 6.0), (0.0, 1.0, 5.0, 6.02, 6.92, 7.92))
    out = retime(src, r)
    assert out.t_s[-1] == pytest.approx(7.92, abs=1e-3)
    assert np.allclose(np.diff(out.t_s), 0.001)
    # every re-timed point lies on the original path (the arc of radius 100)
    radius = np.linalg.norm(out.ball_mm[:, :2], axis=1)
    assert np.abs(radius - 100).max() < 1e-9 + 1e-6
    # each instant maps back through the knots: the ball where the source was then
    for t_new, t_src in ((2.0, 1.5), (3.0, 2.0), (5.5, 3.0), (6.47, 4.5)):
        k = int(round(t_new / 0.001))
        j = int(round(t_src / 0.001))
        assert np.linalg.norm(out.ball_mm[k] - src.ball_mm[j]) < 1e-6
    # the first run's peak speed halves, the second's grows by 1/0.9
    peak = lambda s, a, b: s.speed_mm_per_s[(s.t_s > a) & (s.t_s < b)].max()  # noqa: E731
    assert peak(out, 1, 5) == pytest.approx(peak(src, 1, 3) / 2, rel=1e-3)
    assert peak(out, 6.02, 6.92) == pytest.approx(peak(src, 4, 5) / 0.9, rel=1e-3)
    # the labels follow their samples: the dwells stay dwells
    assert set(out.phase[(out.t_s > 5.1) & (out.t_s < 5.9)]) == {"dwell"}


def test_a_retiming_refuses_knots_out_of_order():
    with pytest.raises(ValueError):
        Retiming((0.0, 2.0, 1.0), (0.0, 1.0, 2.0))
    with pytest.raises(ValueError):
        Retiming((0.0, 1.0), (0.0, 1.0, 2.0))
