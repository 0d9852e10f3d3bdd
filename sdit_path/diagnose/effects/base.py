"""What every effect of the library is: a compact physical model of something a real
ballbar trace holds beyond the simulated geometry (domain brief, section 3), as
regressor columns (um of bar reading per unit of a parameter) on a set of samples;
an effect with a nonlinear parameter (a time constant, a pitch, a frequency, a window)
first searches it on the current residual.  Axis effects act on a machine axis and
reach the bar through ``Context.gain`` (the bar reading change per unit axis error), so
they hold for 3- and 5-axis machines alike.

An effect declares its traits on its class (name, family, what it aliases with,
whether it is time-locked or geometric, its limits as a read-only mapping); the
registry (:mod:`sdit_path.diagnose.effects`) derives every name list and table from
them.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import ClassVar

import numpy as np

from ...reading.context import Context
from ...reading.rows import BLOCK_ROWS


@dataclass(frozen=True, slots=True)
class Samples:
    """A set of trace samples: ``idx : (n,)`` nearest trajectory sample, ``tau_s : (n,)``
    exact program time."""

    idx: np.ndarray
    tau_s: np.ndarray

    def take(self, keep: np.ndarray) -> "Samples":
        return Samples(self.idx[keep], self.tau_s[keep])


#: an orthonormal basis (n, k) of columns fitted beside a searched effect's, or None:
#: set by :func:`fitted_beside` while a search runs
_BESIDE: contextvars.ContextVar = contextvars.ContextVar("beside", default=None)


def beside_basis() -> np.ndarray | None:
    """The basis :func:`fitted_beside` set for the search running now, or None."""
    return _BESIDE.get()


@contextlib.contextmanager
def fitted_beside(basis: np.ndarray | None):
    """Within this block, every search judges its columns as fitted together with the
    columns ``basis`` spans (``r`` orthogonal to them): the reduction a joint fit would
    give.  A raw projection lets the earlier fit keep what the new columns share with it
    (a set-up fitted alone takes part of a smoothing's shrink while moving, and the
    smoothing's search then prefers its shortest filter; hard case:
    blind-bad-SDIT_B-s1-46)."""
    token = _BESIDE.set(basis)
    try:
        yield
    finally:
        _BESIDE.reset(token)


#: what one effect's :func:`memo` keeps at most (24 lagged axis rates of a 5-minute
#: program at 1 kHz are 170 MB, of an hour-long one 2 GB; 16 MB keeps the last two)
MEMO_BYTES = 16 << 20


def memo(cache: dict, ctx: Context, value: float, make, digits: int = 9):
    """``make()`` for one context and parameter value, kept in ``cache`` (at most 24
    entries, the grid and the profiled values of one diagnosis, and
    :data:`MEMO_BYTES`: the oldest go first, the newest stays).  The context rides
    along with its result so that its id cannot be reused while cached."""
    key = (id(ctx), round(value, digits) if isinstance(value, float) else value)
    if key not in cache:
        made = make()
        size = lambda v: sum(a.nbytes for a in (v if isinstance(v, tuple) else (v,))  # noqa: E731
                             if isinstance(a, np.ndarray))
        total = size(made) + sum(size(v) for _, v in cache.values())
        while cache and (len(cache) >= 24 or total > MEMO_BYTES):
            total -= size(cache.pop(next(iter(cache)))[1])
        cache[key] = (ctx, made)
    return cache[key][1]


def filtered_blocks(b, a, n: int, rows, zi, block: int = BLOCK_ROWS):
    """``lfilter(b, a, X, axis=0, zi=zi)`` of ``X : (n, k)`` a block of samples at a
    time, ``rows(start, stop)`` giving those rows of ``X``: yields ``(start, stop, y)``,
    the filter's state carried from block to block, so the same numbers as filtered
    whole (where a tall program's whole signal, its output and the filter's copies are
    hundreds of MB)."""
    from scipy.signal import lfilter

    for start in range(0, n, block):
        stop = min(start + block, n)
        y, zi = lfilter(b, a, rows(start, stop), axis=0, zi=zi)
        yield start, stop, y


def projection_gain(cols: np.ndarray, r: np.ndarray) -> float:
    """Reduction of ``|r|^2`` by least squares on ``cols`` (fitted beside
    :func:`fitted_beside`'s columns, if any)."""
    if cols.size == 0:
        return 0.0
    Q = _BESIDE.get()
    if Q is not None and Q.shape[0] == cols.shape[0]:
        cols = cols - Q @ (Q.T @ cols)
    coef, *_ = np.linalg.lstsq(cols, r, rcond=None)
    fit = cols @ coef
    return float(r @ r - (r - fit) @ (r - fit))


#: a column whose best projection takes less than this share of the residual's energy
#: explains nothing (an axis the bar does not see at these poses)
NEGLIGIBLE = 1e-6


def grid_search(grid, score, spacing) -> float:
    """The best value of a one-dimensional parameter: ``score`` on ``grid``, then on 9
    points (``np.geomspace`` or ``np.linspace``) between the best one's neighbours."""
    k = int(np.argmax([score(v) for v in grid]))
    fine = spacing(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)], 9)
    return float(fine[int(np.argmax([score(v) for v in fine]))])


def gain2(s: np.ndarray, c: np.ndarray, r: np.ndarray) -> np.ndarray:
    """Projection gains of ``r (n,)`` on many column pairs ``s, c : (m, n)`` at once."""
    ss, cc, sc = (s * s).sum(1), (c * c).sum(1), (s * c).sum(1)
    sr, cr = s @ r, c @ r
    det = ss * cc - sc * sc
    det = np.where(det > 1e-300, det, np.inf)
    a = (cc * sr - sc * cr) / det
    b = (ss * cr - sc * sr) / det
    return a * sr + b * cr


def ripple_gains(x: np.ndarray, g: np.ndarray, r: np.ndarray, inv: np.ndarray,
                  block: int = 64) -> np.ndarray:
    """:func:`gain2` of ``r`` on the pairs ``g sin(2 pi x f), g cos(2 pi x f)`` for the
    evenly spaced spatial frequencies ``inv``, from the sums the pairs' products reduce
    to: with ``z = exp(i 2 pi x f)``, ``sum g^2 sin^2 = (sum g^2 - Re sum g^2 z^2) / 2``,
    ``sum g^2 cos^2 = (sum g^2 + Re sum g^2 z^2) / 2``, ``sum g^2 sin cos = Im sum g^2 z^2
    / 2``, ``sum g r sin = Im sum g r z`` and ``sum g r cos = Re sum g r z``.  Within a
    block of frequencies ``z`` steps by multiplication (64 steps: a phase error of
    ~1e-14 rad), each block starting from ``exp`` again."""
    g2, gr = g * g, g * r
    total = float(g2.sum())
    out = np.zeros(len(inv))
    # (one frequency alone never steps)
    step = np.exp(2j * np.pi * x * (inv[1] - inv[0])) if len(inv) > 1 else np.ones(len(x), complex)
    for b in range(0, len(inv), block):
        m = min(block, len(inv) - b)
        Z = np.empty((m, len(x)), complex)
        Z[0] = np.exp(2j * np.pi * x * inv[b])
        for k in range(1, m):
            np.multiply(Z[k - 1], step, out=Z[k])
        s1 = Z @ gr
        Z *= Z
        s2 = Z @ g2
        ss, cc, sc = 0.5 * (total - s2.real), 0.5 * (total + s2.real), 0.5 * s2.imag
        sr, cr = s1.imag, s1.real
        det = ss * cc - sc * sc
        det = np.where(det > 1e-300, det, np.inf)
        a = (cc * sr - sc * cr) / det
        bb = (ss * cr - sc * sr) / det
        out[b:b + m] = a * sr + bb * cr
    return out


class Effect:
    """One effect of the library.  A subclass declares what it is in class attributes
    (its traits, below) and how it reads (``search``, ``columns``, ``parameters``); the
    registry derives every name list and table from the traits, so that nothing outside
    the effect classes names an effect."""

    #: the name reports and ``perturb --effect`` use (``servo_lag``), and a short title
    name: ClassVar[str] = ""
    title: ClassVar[str] = ""
    #: the name as the trade says it in a report ("" : the name with spaces)
    trade_name: ClassVar[str] = ""
    #: listed on the report's first page even where no recording shows it (the order);
    #: None: listed only where found
    headline: ClassVar[int | None] = None
    #: what a parameter is, where its name and unit alone do not say it
    parameter_notes: ClassVar[Mapping[str, str]] = MappingProxyType({})
    #: how common the effect is on a healthy machining centre (0: the most common): the
    #: order that decides between effects the data cannot tell apart (equal evidence)
    commonness: ClassVar[int] = -1
    #: a more general geometric error could stand in for it (position-locked or slow:
    #: the held-out check against smooth geometry beyond the library judges it)
    geometric: ClassVar[bool] = False
    #: its signal is read through timing at the millisecond level: never named with
    #: high confidence on a recording whose timing is weak, and not read again from the
    #: settled dwells (where it does not act)
    time_locked: ClassVar[bool] = False
    #: part of the mounting (the ball centres, the bar length): where no single effect
    #: passes a selection step, the mounting's parts are tried together
    mounting: ClassVar[bool] = False
    #: judged again at the settled timing whatever the first pass found (at the first
    #: timing a position-locked effect may have stood in for it)
    judged_again: ClassVar[bool] = False
    #: effects one recording at one feed cannot tell from this one -> the experiment
    #: that separates them (each pair declared on one of its two classes)
    aliases: ClassVar[Mapping[str, str]] = MappingProxyType({})
    #: effects only some programs tell from this one (through the bar directions and
    #: positions they cover) -> the program that separates them; never merged when both
    #: are selected
    program_aliases: ClassVar[Mapping[str, str]] = MappingProxyType({})
    #: the alias (a key of ``aliases``) whose reading puts the recording's start
    #: elsewhere: the timing is searched with it in this one's place too
    timing_alias: ClassVar[str | None] = None
    #: nonlinear parameters that take discrete values (not differentiated)
    discrete: ClassVar[tuple[str, ...]] = ()
    unit_note = ""

    def __init_subclass__(cls, **kwargs):
        super().__init_subclass__(**kwargs)
        # the tables a class declares are read-only, its own and not its parent's
        for key in ("limits", "aliases", "program_aliases", "parameter_notes"):
            value = cls.__dict__.get(key)
            if isinstance(value, dict):
                setattr(cls, key, MappingProxyType(dict(value)))

    @classmethod
    def create(cls, machine, travel) -> "Effect":
        """The effect for one machine and its tested travel (most need neither)."""
        return cls()

    @classmethod
    def covered_by(cls, options) -> bool:
        """Does the identification's geometric model (``ModelOptions``) hold what this
        effect reads?  Then it is part of the geometry, not a nuisance of it."""
        return False

    def locked_to_program(self, nonlinear: dict) -> bool:
        """Is the finding's reading locked to the program, to be fitted beside the
        timing?  (A steady ripple is locked to time instead: it would pull the clock.)"""
        return True

    def shape_parameters(self, nonlinear: dict) -> dict:
        """The nonlinear parameters that shape the finding's reading (its search's
        hints left out): a change in them reshapes the finding."""
        return dict(nonlinear)

    def search(self, ctx: Context, s: Samples, r: np.ndarray) -> dict | None:
        return {}

    def columns(self, ctx: Context, s: Samples, nl: dict) -> tuple[np.ndarray, tuple[str, ...]]:
        raise NotImplementedError

    def parameters(self, coef: np.ndarray, labels, nl: dict, ctx: Context) -> dict:
        out = {k: float(v) for k, v in nl.items()}
        out.update({lab: float(c) for lab, c in zip(labels, coef)})
        return out

    def physical(self, coef: np.ndarray) -> bool:
        return True

    def from_fit(self, nl: dict, coef: np.ndarray, labels) -> dict | None:
        """Nonlinear parameters read back from the coefficients fitted with every other
        finding in (a lag difference that shapes its own second order), or None when
        none are."""
        return None

    #: a nonlinear parameter that trades with the recording's start (a lag: the alignment
    #: puts it into the offset) and the grid it is profiled on with the timing, or None
    timing_parameter: tuple[str, tuple[float, ...]] | None = None
    #: a lag at the far end of its grid is not this effect; other timing parameters (a
    #: pulse's onset speed) may lie at either end
    timing_end_implausible: bool = True
    #: ``search`` takes ``fixed=`` (parameters pinned by a profile with the timing)
    searches_with_fixed: bool = False
    #: the effect's shape may hold the recording's timing (pulses after reversals on a
    #: trace with little else), and its shape and the start trade with each other: its
    #: search is repeated with the effect shifted in time (``diagnose.shape_scan``)
    shape_holds_timing: bool = False

    #: how the effect's reading changes when the same path is run again: in the reverse
    #: direction it is multiplied by ``reverse`` (-1: odd in the velocity, +1: even;
    #: None: not that simple), at half the feed by 0.5 ** ``feed_power`` (None: not a
    #: power of the feed).  Used to name the run that separates it from the geometry.
    reverse: int | None = None
    feed_power: float | None = None

    #: parameter -> largest plausible magnitude on a machining centre (about twice the
    #: "bad" end of the domain brief's table); a fit beyond it is not this effect
    limits: ClassVar[Mapping[str, float]] = MappingProxyType({})

    def unsure_in_time(self, ctx: Context, params: dict) -> np.ndarray | None:
        """Grid samples where the effect's model, as found (``params``: its sizes by
        label), leaves the reading open - a fine structure not locked to the program -
        or None.  The timing is read again without them and the two readings compared
        (``diagnose.settle``)."""
        return None

    def implausible(self, params: dict) -> str | None:
        for key, value in params.items():
            for pattern, lim in self.limits.items():
                if isinstance(value, float) and _match(key, pattern) and abs(value) > lim:
                    return f"{key} = {value:.4g} exceeds the plausible {lim:g}"
        if self.timing_parameter and self.timing_end_implausible:
            # a lag at the far end of its search: the data want a longer one, which is not
            # this effect (a backlash on the equator layer, its play taken up over a slow
            # reversal, reads as a mismatch with its common lag at the end of its grid
            # beside a stick-slip; hard case: analyse-s2-2)
            key, grid = self.timing_parameter
            value = params.get(key)
            if isinstance(value, float) and grid[-1] > 0 and value >= grid[-1] * (1 - 1e-9):
                return f"{key} = {value:.4g} at the end of its search ({grid[-1]:g})"
        return None


def _match(key: str, pattern: str) -> bool:
    if pattern.endswith("*"):
        return key.startswith(pattern[:-1])
    if pattern.startswith("*"):
        return key.endswith(pattern[1:])
    return key == pattern


def linear_axes(ctx: Context):
    """Linear axes the bar can see."""
    return [j for j in ctx.linear if j in ctx.observable]
