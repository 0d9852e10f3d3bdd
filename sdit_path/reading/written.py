"""The program as written for its controller: where its path leaves the planned one.

The plan's trajectory puts the ball on the planned curve, on the sphere to nanometres.
A control runs the program as written, and for some controllers that is not the curve:

* LinuxCNC gets straight G1 chords between vertices on the sphere; between them the
  ball dips inside the sphere by up to the chord tolerance (``post.chord_tolerance_um``,
  0.1 um by default): a reading a ballbar sees, with the chords' pitch, which a clean
  recording of a LinuxCNC machine shows and which, left out of the expected reading,
  is read as a lag, a smoothing or a cyclic error.  In the machine frame (G93, a
  5-axis program) the joints move linearly between vertices, and the ball's path is
  the kinematics of that motion.
* FANUC, Haas and HEIDENHAIN get chords too (within ``max_radial_deviation_um`` of
  plan.json, which a control reading 4 decimals holds to its grid), read back with our
  reader of each dialect; under HEIDENHAIN's TCPM (a 5-axis program) the ball moves
  straight along each chord of the table frame.
* SINUMERIK 840D gets a BSPLINE whose rounded control points keep the sphere to a few
  nanometres, a FANUC G06.2 NURBS to a few hundredths of a micrometre
  (``max_radial_deviation_um`` in plan.json): below any recording's resolution, taken
  as zero.

:func:`written_deviation_um` gives, for every sample of a program's trajectory, the
change of the bar's length where the control's path passes that sample: the point of
the program's path closest to it (the chords stay within a micrometre of the curve,
``post.chord_curve_tolerance_um``), its distance from the pivot less the sample's.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..errors import ConfigError
from ..machine.kinematics import Kinematics


def written_deviation_um(plan, program: str, ball_mm: np.ndarray, moving: np.ndarray
                         ) -> np.ndarray:
    """``(n,)`` um: the bar length along the program as written for the plan's
    controller (:attr:`PlanFiles.ran_on`) less that along the planned path, at the
    trajectory's ball positions ``ball_mm : (n, 3)``; zero where the machine stands
    (``moving`` False) and for controllers that write the curve itself."""
    out = np.zeros(len(ball_mm))
    if plan.ran_on not in CHORD_READERS or plan.motion_of(program) is not None:
        return out  # a spline, or the control's motion: the program as written already
    found = plan.program_text(program)
    if found is None:
        return out
    text, entry = found
    cfg = plan.config
    kin = Kinematics(cfg.machine)
    frame = (entry.get("frame") or {}).get("name", "table")
    # under TCPM the control keeps the ball on the straight chord of the table frame
    table = frame in ("table", "tcpm")
    axes = ("X", "Y", "Z") if table else tuple(kin.names)
    try:
        ends = _chord_vertices(plan.ran_on, text, axes)
    except (ValueError, KeyError, IndexError) as exc:
        raise ConfigError(entry["file"], f"cannot read its moves: {exc}") from None
    rotary = np.array([not table and kin.axes[kin.index[a]].is_rotary for a in axes])

    def to_table(pos: np.ndarray) -> np.ndarray:
        if table:
            return pos
        q = np.zeros((len(pos), len(kin.names)))
        for col, name in enumerate(axes):
            q[:, kin.index[name]] = np.radians(pos[:, col]) if rotary[col] else pos[:, col]
        return kin.forward(q)

    if not ends:
        return out
    a_prog = np.vstack([e[:-1] for e in ends])
    b_prog = np.vstack([e[1:] for e in ends])
    keep = np.any(a_prog != b_prog, axis=1)
    a_prog, b_prog = a_prog[keep], b_prog[keep]
    a, b = to_table(a_prog), to_table(b_prog)
    pivot = np.asarray(cfg.ballbar.pivot_mm, dtype=float)
    idx = np.flatnonzero(moving)
    if not len(idx) or not len(a):
        return out
    p = np.asarray(ball_mm, dtype=float)[idx]
    # candidate chords: those whose middle is among the nearest few to the sample
    tree = cKDTree(0.5 * (a + b))
    _, near = tree.query(p, k=min(6, len(a)))
    if near.ndim == 1:
        near = near[:, None]
    d = b[near] - a[near]                                     # (m, k, 3)
    f = np.einsum("mkj,mkj->mk", p[:, None, :] - a[near], d) / np.maximum(
        np.einsum("mkj,mkj->mk", d, d), 1e-300)
    f = np.clip(f, 0.0, 1.0)
    foot = a[near] + f[..., None] * d
    best = np.argmin(np.linalg.norm(foot - p[:, None, :], axis=2), axis=1)
    rows = np.arange(len(idx))
    chord, frac = near[rows, best], f[rows, best]
    if table:
        on_path = foot[rows, best]
    else:  # the joints move linearly: the ball's path is their kinematics
        on_path = to_table(a_prog[chord] + frac[:, None] * (b_prog[chord] - a_prog[chord]))
    out[idx] = (np.linalg.norm(on_path - pivot, axis=1)
                - np.linalg.norm(p - pivot, axis=1)) * 1e3
    return out


#: the chord controllers whose programs are read back here
CHORD_READERS = ("linuxcnc", "fanuc", "haas", "heidenhain")


def _chord_vertices(controller: str, text: str, axes: tuple[str, ...]) -> list[np.ndarray]:
    """The program's vertices, stretch by stretch (cut at its dwells and stops): each
    ``(k, m)`` in program coordinates, in the order of ``axes``."""
    if controller == "linuxcnc":
        from ..timing.linuxcnc_tp import stretches  # the program's reader, shared

        return [np.vstack([st.start[None, :], st.end]) for st in stretches(text, axes)]
    from ..nc.readback import read_heidenhain, read_iso

    got = read_heidenhain(text) if controller == "heidenhain" else read_iso(text)
    cols = [got.axes.index(a) for a in axes]
    pts = got.points[:, cols]
    cuts = sorted({i for _, _, i in got.dwells} | {int(np.searchsorted(got.lines, s)) - 1
                                                   for s in got.stops})
    # the test's poses, not the operator's way to the bar and back
    test = range(len(pts))[got.test]
    first, last = test.start, test.stop - 1
    bounds = sorted({first, last} | {c for c in cuts if first < c < last})
    return [pts[a:b + 1] for a, b in zip(bounds[:-1], bounds[1:]) if b > a]
