"""The effect library: one registry of effect classes, from which every name list and
trait table of the diagnosis is derived.

To add an effect (``docs/development/add-an-effect.md``): a class in this package with
its traits, its entry in :data:`EFFECTS`, its physics in the simulator
(``sdit_path.sim.perturb``) and in the independent generator (``validation/
physics_gen.py``).  Nothing else names it.
"""

from __future__ import annotations

from .base import Effect, Samples, fitted_beside, linear_axes, projection_gain
from .cyclic import CyclicError
from .drift import ThermalDrift
from .friction import ReversalSpike, StickSlip
from .geometry import GeometryBeyond, ScaleMismatch, Squareness
from .play import Backlash, LateralPlay
from .servo import ServoLag, ServoMismatch
from .setup import BarLength, SetupOffset
from .smoothing import ContourSmoothing
from .vibration import Vibration

#: the library, in the order the selection tries its candidates
EFFECTS: tuple[type[Effect], ...] = (
    SetupOffset, BarLength, ThermalDrift, ServoLag, ServoMismatch, Backlash, ReversalSpike,
    LateralPlay, CyclicError, Vibration, StickSlip, Squareness, ScaleMismatch,
    ContourSmoothing)

EFFECT_NAMES: tuple[str, ...] = tuple(e.name for e in EFFECTS)
BY_NAME: dict[str, type[Effect]] = {e.name: e for e in EFFECTS}
#: how common each effect is on a healthy machining centre, most common first: the
#: order that decides between effects the data cannot tell apart (equal evidence)
PRIOR_ORDER: tuple[str, ...] = tuple(e.name for e in sorted(EFFECTS, key=lambda e: e.commonness))
#: findings that a more general geometric error could be standing in for
GEOMETRIC: frozenset[str] = frozenset(e.name for e in EFFECTS if e.geometric)
#: effects whose signal is read through timing at the millisecond level
TIME_LOCKED: frozenset[str] = frozenset(e.name for e in EFFECTS if e.time_locked)
#: the mounting's own parameters, tried together where neither passes alone
MOUNTING: tuple[str, ...] = tuple(e.name for e in EFFECTS if e.mounting)
#: judged again at the settled timing whatever the first pass found
JUDGED_AGAIN: frozenset[str] = frozenset(e.name for e in EFFECTS if e.judged_again)
#: pairs one recording at one feed cannot tell apart -> the experiment that separates them
ALIASED: dict[frozenset[str], str] = {frozenset({e.name, other}): how for e in EFFECTS
                                      for other, how in e.aliases.items()}
#: pairs only some programs tell apart -> the program that separates them
PROGRAM_ALIASED: dict[frozenset[str], str] = {frozenset({e.name, other}): how for e in EFFECTS
                                              for other, how in e.program_aliases.items()}
#: the aliased pairs whose timing is searched with either
TIMING_ALIASED: tuple[frozenset[str], ...] = tuple(frozenset({e.name, e.timing_alias})
                                                   for e in EFFECTS if e.timing_alias)


def library(machine, travel) -> list[Effect]:
    """Every effect of the library for one machine and its tested travel."""
    return [e.create(machine, travel) for e in EFFECTS]


def _check_registry() -> None:
    """The traits must make a registry: unique names and ranks, aliases of known
    effects, each pair declared once."""
    if len(BY_NAME) != len(EFFECTS) or not all(EFFECT_NAMES):
        raise TypeError("effects: every effect needs its own name")
    if sorted(e.commonness for e in EFFECTS) != list(range(len(EFFECTS))):
        raise TypeError("effects: commonness must rank the effects 0..n-1, each once")
    pairs = [frozenset({e.name, o}) for e in EFFECTS
             for o in (*e.aliases, *e.program_aliases)]
    for e in EFFECTS:
        for other in (*e.aliases, *e.program_aliases):
            if other not in BY_NAME or other == e.name:
                raise TypeError(f"effects: {e.name} aliases the unknown effect {other!r}")
        if e.timing_alias is not None and e.timing_alias not in e.aliases:
            raise TypeError(f"effects: {e.name}'s timing alias is not one of its aliases")
    if len(pairs) != len(set(pairs)):
        raise TypeError("effects: an aliased pair is declared twice")


_check_registry()

__all__ = ["ALIASED", "BY_NAME", "EFFECTS", "EFFECT_NAMES", "GEOMETRIC", "JUDGED_AGAIN",
           "MOUNTING", "PRIOR_ORDER", "PROGRAM_ALIASED", "TIMING_ALIASED", "TIME_LOCKED",
           "Backlash", "BarLength", "ContourSmoothing", "CyclicError", "Effect",
           "GeometryBeyond", "LateralPlay", "ReversalSpike", "Samples", "ScaleMismatch",
           "ServoLag", "ServoMismatch", "SetupOffset", "Squareness", "StickSlip",
           "ThermalDrift", "Vibration", "fitted_beside", "library", "linear_axes",
           "projection_gain"]
