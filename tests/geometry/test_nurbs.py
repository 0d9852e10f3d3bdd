from __future__ import annotations

import numpy as np
import pytest

from sdit_path.errors import PlanError
from sdit_path.geometry.curves import MeridianCurve
from sdit_path.geometry.nurbs import BSplineCurve, fit_run, max_radial_deviation


def _geomdl_eval(curve: BSplineCurve, u: np.ndarray) -> np.ndarray:
    a, b = curve.domain
    return np.array(curve.to_geomdl().evaluate_list(list((u - a) / (b - a))))


@pytest.mark.parametrize("rational", [False, True])
def test_vectorised_evaluation_matches_geomdl(rational):
    rng = np.random.default_rng(7)
    q = rng.normal(size=(9, 3)) * 50
    knots = np.concatenate([[0, 0, 0], np.arange(0, 7) * 2.5, [15, 15, 15]])
    w = rng.uniform(0.3, 2.5, 9) if rational else None
    curve = BSplineCurve(3, knots, q, w)
    u = np.linspace(0, 15, 101)
    assert np.abs(curve.evaluate(u) - _geomdl_eval(curve, u)).max() < 1e-9


def test_exact_quadratic_arc_is_on_the_circle():
    # 90 deg arc, weights (1, cos 45, 1): exact; deviation only from float rounding
    c = np.array([0.0, 0.0, 0.0])
    arc = BSplineCurve(2, [0, 0, 0, 1, 1, 1], [[10, 0, 0], [10, 10, 0], [0, 10, 0]],
                       [1, np.sqrt(0.5), 1])
    assert max_radial_deviation(arc, c, 10.0)[0] < 1e-12
    # the 4-decimal weight of the brief costs ~0.17 um per 100 mm
    coarse = BSplineCurve(2, arc.knots, arc.control_points_mm * 10, [1, 0.7071, 1])
    assert 0.1e-3 < max_radial_deviation(coarse, c, 100.0)[0] < 0.25e-3


def test_reversed_is_the_same_curve_backwards():
    rng = np.random.default_rng(3)
    curve = BSplineCurve(3, [0, 0, 0, 0, 1, 2, 3, 3, 3, 3], rng.normal(size=(6, 3)))
    u = np.linspace(0, 3, 31)
    assert np.allclose(curve.reversed().evaluate(u), curve.evaluate(3 - u)[:], atol=1e-12)


def test_fit_meets_tolerance_on_rounded_control_points():
    c = np.array([5.0, -3.0, 20.0])
    arc = MeridianCurve(c, 120.0, 0.7, 0.0, np.radians(60))
    fit = fit_run([arc], c, 120.0, arc(np.array([0.0]))[0], arc(np.array([1.0]))[0],
                  tolerance_mm=1e-5, decimals=6)
    q = fit.curve.control_points_mm
    assert np.array_equal(q, np.round(q, 6))
    # independent dense check of the claim
    u = np.linspace(*fit.curve.domain, 200001)
    r = np.linalg.norm(fit.curve.evaluate(u) - c, axis=1) - 120.0
    assert np.abs(r).max() <= 1e-5
    assert fit.piece_max_deviation_mm[0] >= np.abs(r).max() * 0.999


def test_fit_refuses_decimals_too_coarse_for_the_tolerance():
    c = np.zeros(3)
    arc = MeridianCurve(c, 100.0, 0.0, 0.0, 1.0)
    with pytest.raises(PlanError, match="post.decimals = 4"):
        fit_run([arc], c, 100.0, arc(np.array([0.0]))[0], arc(np.array([1.0]))[0],
                tolerance_mm=1e-5, decimals=4)


def test_geomdl_exchange_round_trip():
    rng = np.random.default_rng(11)
    curve = BSplineCurve(2, [0, 0, 0, 0.5, 1, 1, 1], rng.normal(size=(4, 3)), [1, 0.8, 1.3, 1])
    back = BSplineCurve.from_geomdl(curve.to_geomdl())
    u = np.linspace(0, 1, 11)
    assert np.abs(back.evaluate(u) - curve.evaluate(u)).max() < 1e-12
