from __future__ import annotations

import math

import numpy as np
import pytest

from sdit_path.geometry.curves import WaveCurve, projected_radius, tangent
from sdit_path.geometry.hemisphere import partition


def _layer_curves(config, layer):
    h = partition(config)
    la = next(x for x in h.layers if x.name == layer)
    span = 2 * math.pi / h.nodes_per_track
    c = config.test.curve
    return h, la, [WaveCurve(h.centre_mm, h.radius_mm, la.lower_elevation_rad, la.upper_elevation_rad,
                             c.amplitude, c.waves_per_sector, span, config.test.projection,
                             s.azimuth_start_rad, s.azimuth_end_rad) for s in la.segments]


@pytest.mark.parametrize("projection", ["stereographic", "vertical"])
@pytest.mark.parametrize("layer", ["A", "C", "E"])
def test_exact_curves_stay_on_sphere_and_inside_their_patch(config_with, projection, layer):
    cfg = config_with("projection", f'"{projection}"')
    h, la, curves = _layer_curves(cfg, layer)
    t = np.linspace(0, 1, 2001)
    for seg, curve in zip(la.segments, curves):
        p = curve(t) - h.centre_mm
        r = np.linalg.norm(p, axis=1)
        assert np.abs(r - h.radius_mm).max() < 1e-9
        elev = np.arcsin(np.clip(p[:, 2] / r, -1, 1))
        az = np.mod(np.arctan2(p[:, 1], p[:, 0]), 2 * math.pi)
        az[az > 2 * math.pi - 1e-9] = 0.0
        if seg.azimuth_end_rad >= 2 * math.pi - 1e-12:
            az[az < 1e-6] = 2 * math.pi
        assert elev.min() >= la.lower_elevation_rad - 1e-9
        assert elev.max() <= la.upper_elevation_rad + 1e-9
        assert az.min() >= seg.azimuth_start_rad - 1e-9
        assert az.max() <= seg.azimuth_end_rad + 1e-9
        # the planar design curve lies between the projected circles
        rho = np.linalg.norm(curve.planar(t), axis=1)
        lo = projected_radius(la.upper_elevation_rad, h.radius_mm, projection)
        hi = projected_radius(la.lower_elevation_rad, h.radius_mm, projection)
        assert rho.min() >= lo - 1e-9 and rho.max() <= hi + 1e-9


@pytest.mark.parametrize("projection", ["stereographic", "vertical"])
def test_consecutive_segments_join_with_continuous_tangent(config_with, projection):
    cfg = config_with("projection", f'"{projection}"')
    for layer in "ABCDE":
        _, _, curves = _layer_curves(cfg, layer)
        for a, b in zip(curves, curves[1:] + curves[:1]):
            assert np.allclose(a(np.array([1.0]))[0], b(np.array([0.0]))[0], atol=1e-9)
            ta, tb = tangent(a, 1.0), tangent(b, 0.0)
            assert np.degrees(np.arccos(np.clip(ta @ tb, -1, 1))) < 0.01


def test_wave_touches_both_tracks(default_config):
    h, la, curves = _layer_curves(default_config, "B")
    p = np.vstack([c(np.linspace(0, 1, 4001)) for c in curves]) - h.centre_mm
    elev = np.degrees(np.arcsin(p[:, 2] / h.radius_mm))
    assert elev.min() == pytest.approx(18.0, abs=1e-6)
    assert elev.max() == pytest.approx(36.0, abs=1e-4)


def test_overridden_sectors_stay_in_their_patch_and_join_their_neighbours(default_text):
    from sdit_path.config import parse_config
    from sdit_path.geometry.paths import PathBuilder

    text = default_text + "".join(
        f'\n[[test.curve.override]]\nsector = "{s}"\n{body}\n' for s, body in
        (("D3", "amplitude = 0.4\nwaves_per_sector = 3\nprojection = \"vertical\""),
         ("D4", "waves_per_sector = 2"), ("A1", "amplitude = 0.3\nprojection = \"vertical\"")))
    cfg = parse_config(text, "t.toml")
    h = partition(cfg)
    builder = PathBuilder(cfg, h)
    t = np.linspace(0, 1, 1001)
    for la in (x for x in h.layers if x.name in "AD"):
        curves = [builder._wave(la, s) for s in la.segments]
        for a, b in zip(curves, curves[1:] + curves[:1]):
            assert np.allclose(a(np.array([1.0]))[0], b(np.array([0.0]))[0], atol=1e-9)
            ta, tb = tangent(a, 1.0), tangent(b, 0.0)
            assert np.degrees(np.arccos(np.clip(ta @ tb, -1, 1))) < 0.01
        for seg, c in zip(la.segments, curves):
            p = c(t) - h.centre_mm
            assert np.abs(np.linalg.norm(p, axis=1) - h.radius_mm).max() < 1e-9
            elev = np.arcsin(p[:, 2] / h.radius_mm)
            assert elev.min() >= la.lower_elevation_rad - 1e-9
            assert elev.max() <= la.upper_elevation_rad + 1e-9
        d3 = [c for s, c in zip(la.segments, curves) if s.sector == 3]
        if la.name == "D":
            assert (d3[0].amplitude, d3[0].waves, d3[0].projection) == (0.4, 3, "vertical")
