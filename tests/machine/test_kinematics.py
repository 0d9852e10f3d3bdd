from __future__ import annotations

import math

import numpy as np
import pytest

from sdit_path.config import load_config, sample_path
from sdit_path.geometry.hemisphere import partition
from sdit_path.geometry.paths import PathBuilder
from sdit_path.machine.kinematics import Kinematics
from sdit_path.machine.poses import layer_poses
from sdit_path.machine.schedule import RotarySchedule


@pytest.fixture(scope="module")
def five():
    return load_config(sample_path("bc_table_5axis.toml"))


def test_fk_of_ik_is_identity_over_the_whole_rotary_range(five):
    kin = Kinematics(five.machine)
    rng = np.random.default_rng(1)
    n = 20000
    p = rng.uniform(-300, 300, size=(n, 3))
    b_lo, b_hi = five.machine.axis("B").travel
    c_lo, c_hi = five.machine.axis("C").travel
    angles = {"B": rng.uniform(b_lo, b_hi, n), "C": rng.uniform(c_lo, c_hi, n)}
    q = kin.inverse(p, angles)
    assert np.abs(kin.forward(q) - p).max() < 1e-9
    assert np.array_equal(q[:, kin.index["B"]], angles["B"])


def test_fk_matches_a_hand_built_chain(five):
    """Independent of the module: the B-C table built from 4x4 matrices by hand."""
    kin = Kinematics(five.machine)
    rng = np.random.default_rng(2)
    for _ in range(50):
        x, y, z = rng.uniform(-100, 100, 3)
        b, c = rng.uniform(-2, 2, 2)

        def about(axis, point, angle):
            k = np.array(axis, float)
            K = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
            R = np.eye(3) + math.sin(angle) * K + (1 - math.cos(angle)) * K @ K
            T = np.eye(4)
            T[:3, :3] = R
            T[:3, 3] = np.array(point) - R @ np.array(point)
            return T

        def shift(v):
            T = np.eye(4)
            T[:3, 3] = v
            return T

        table = shift([-x, 0, 0]) @ shift([0, -y, 0]) @ about([0, 1, 0], [0, 0, -250], b) \
            @ about([0, 0, 1], [0, 0, -250], c)
        ball = shift([0, 0, z]) @ np.array([0, 0, -100.0, 1])
        expected = (np.linalg.inv(table) @ ball)[:3]
        q = np.zeros((1, 5))
        q[0, kin.index["X"]], q[0, kin.index["Y"]], q[0, kin.index["Z"]] = x, y, z
        q[0, kin.index["B"]], q[0, kin.index["C"]] = b, c
        assert np.allclose(kin.forward(q)[0], expected, atol=1e-10)


def test_three_axis_machine_axes_equal_program_coordinates(default_config):
    kin = Kinematics(default_config.machine)
    p = np.random.default_rng(3).uniform(-100, 100, (100, 3))
    assert np.allclose(kin.inverse(p, {}), p, atol=1e-12)


def test_moving_schedule_is_continuous_and_holds_through_the_pole(five):
    hemi = partition(five)
    builder = PathBuilder(five, hemi)
    kin = Kinematics(five.machine)
    c_index = kin.index["C"]
    for layer in (hemi.layers[0], hemi.layers[-1]):
        poses = layer_poses(builder.layer_path(layer), five, kin)
        c = np.concatenate([p.q[:, c_index] for p in poses])
        steps = np.abs(np.diff(c))
        assert steps.max() < math.radians(3.0)          # no unwinding jump, ever
        span = math.degrees(c.max() - c.min())
        assert 355 < span < 365                          # one full turn for the layer
        assert np.isfinite(c).all()
        for p in poses:
            assert np.abs(kin.forward(p.q) - p.points_mm).max() < 1e-9


def test_bar_keeps_its_machine_azimuth_under_the_moving_schedule(five):
    kin = Kinematics(five.machine)
    sched = RotarySchedule(five, kin)
    pivot = np.array(five.ballbar.pivot_mm)
    az = np.radians(np.linspace(0, 350, 36))
    el = np.radians(30.0)
    pts = pivot + 150 * np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az),
                                  np.full_like(az, np.sin(el))], axis=1)
    angles, _ = sched.angles(pts)
    q = kin.inverse(pts, angles)
    rot, trans = kin.table_transform(q)
    bar_machine = np.einsum("nij,nj->ni", rot, pts - pivot)
    azimuth = np.degrees(np.arctan2(bar_machine[:, 1], bar_machine[:, 0]))
    assert np.abs(azimuth).max() < 1e-9                  # always towards +X
    assert np.allclose(np.degrees(angles["B"]), 15.0)     # 45 deg * 30/90


def test_pose_spacing_never_exceeds_the_configured_step(default_config):
    hemi = partition(default_config)
    builder = PathBuilder(default_config, hemi)
    kin = Kinematics(default_config.machine)
    for layer in hemi.layers:
        for p in layer_poses(builder.layer_path(layer), default_config, kin):
            assert np.diff(p.s_mm).max() <= default_config.check.pose_spacing_mm
