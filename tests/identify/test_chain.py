"""The exact error chain and the first-order sensitivities agree to second order."""

from __future__ import annotations

import numpy as np
import pytest

from sdit_path.config import load_config, sample_path
from sdit_path.errormodel.chain import actual_ball, sensitivities
from sdit_path.errormodel.model import ModelOptions, build_model
from sdit_path.machine.kinematics import Kinematics


@pytest.mark.parametrize("sample", ["vmc_3axis.toml", "bc_table_5axis.toml"])
def test_exact_and_first_order_agree_to_second_order(sample):
    cfg = load_config(sample_path(sample))
    kin = Kinematics(cfg.machine)
    rng = np.random.default_rng(0)
    travel = {a.name: (a.travel[0] / 4, a.travel[1] / 4) for a in kin.axes if not a.is_rotary}
    model = build_model(cfg.machine, travel, ModelOptions(linear_order=2, rotary_order=2))
    q = np.column_stack([rng.uniform(a.travel[0] / 4, a.travel[1] / 4, 2000) for a in kin.axes])
    pivot = np.array(cfg.ballbar.pivot_mm)
    J = sensitivities(kin, model, q, pivot)
    d0 = np.linalg.norm(actual_ball(kin, model, np.zeros(len(model.names)), q) - pivot, axis=1)
    theta = rng.normal(size=len(model.names)) * 10  # 10 um / 10 urad typical
    residual = []
    for k in (1.0, 2.0, 4.0):
        d = (np.linalg.norm(actual_ball(kin, model, theta * k, q) - pivot, axis=1) - d0) * 1e3
        residual.append(np.abs(d - J @ (theta * k)).max())
        assert np.abs(d).max() > 20 * k  # the errors do move the reading
    # the first-order model is exact up to terms quadratic in the errors
    assert residual[1] / residual[0] == pytest.approx(4.0, rel=0.1)
    assert residual[2] / residual[1] == pytest.approx(4.0, rel=0.1)
    assert residual[0] < 0.5  # um, for errors of about 10 um / 10 urad


def test_small_rotations_agree_with_scipy():
    """The exact chain's rotations by error vectors (written out element by element)
    against SciPy's own rotation vectors, from machine-error angles to large ones."""
    from scipy.spatial.transform import Rotation
    from sdit_path.errormodel.chain import _small_rotation
    rng = np.random.default_rng(4)
    for scale in (0.0, 1e-12, 1e-6, 1e-3, 0.5, 3.0):
        eps = rng.normal(size=(500, 3)) * scale
        eps[:3] = 0.0
        assert np.abs(_small_rotation(eps) - Rotation.from_rotvec(eps).as_matrix()).max() < 5e-15
