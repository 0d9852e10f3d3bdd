from __future__ import annotations

import math

import numpy as np

from sdit_path.geometry.hemisphere import partition


def test_partition_names_as_the_paper(default_config):
    h = partition(default_config)
    assert [t.name for t in h.tracks] == ["A", "B", "C", "D", "E"]
    ids = [n.id for n in h.nodes]
    assert ids[:6] == ["A-1", "A-2", "A-3", "A-4", "A-5", "A-6"]
    assert ids[-1] == "TOP" and len(ids) == 31
    assert [la.name for la in h.layers] == ["A", "B", "C", "D", "E"]
    assert all(len(la.segments) == 18 for la in h.layers)
    d = next(la for la in h.layers if la.name == "D")
    seg = next(s for s in d.segments if s.id == "D3-2")
    assert (seg.layer, seg.sector, seg.subsegment) == ("D", 3, 2)
    assert math.isclose(math.degrees(seg.azimuth_start_rad), 140.0)
    assert math.isclose(math.degrees(seg.azimuth_end_rad), 160.0)
    e = h.layers[-1]
    assert e.is_cap and e.upper_track == "TOP"
    assert math.isclose(math.degrees(e.upper_elevation_rad), 81.0)


def test_nodes_lie_on_the_sphere(default_config):
    h = partition(default_config)
    for n in h.nodes:
        assert abs(np.linalg.norm(n.position_mm - h.centre_mm) - h.radius_mm) < 1e-12
        assert not n.position_mm.flags.writeable
    a2 = h.node("A-2")
    assert np.allclose(a2.position_mm, [75.0, 150.0 * math.sin(math.pi / 3), 50.0])
