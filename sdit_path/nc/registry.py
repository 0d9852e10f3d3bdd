"""The post-processor registry: an explicit dict, plus an entry-point group for
third-party controllers.  Post-processors are never discovered by file name."""

from __future__ import annotations

from importlib import import_module
from importlib.metadata import entry_points
from typing import Protocol

from ..config import Config, Reader
from ..config.reader import short
from ..errors import UnknownControllerError
from .chords import CornerModel
from .program import Program

ENTRY_POINT_GROUP = "sdit_path.postprocessors"

BUILTIN: dict[str, str] = {
    "sinumerik840d": "sdit_path.postprocessors.sinumerik840d:Sinumerik840D",
    "linuxcnc": "sdit_path.postprocessors.linuxcnc:LinuxCNC",
    "fanuc": "sdit_path.postprocessors.fanuc:Fanuc",
    "fanuc_nurbs": "sdit_path.postprocessors.fanuc_nurbs:FanucNurbs",
    "haas": "sdit_path.postprocessors.haas:Haas",
    "heidenhain": "sdit_path.postprocessors.heidenhain:Heidenhain",
}


class PostProcessor(Protocol):
    """What a controller module provides."""

    name: str
    title: str
    short: str  # a few characters for table headers
    extension: str
    path_form: str  # "spline" (native B-spline) or "chords" (3-D G1 chords)
    #: for "chords": when the control joins two chords at the feed (None: any turn)
    corners: CornerModel | None

    def render(self, program: Program) -> str: ...

    def lint(self, text: str, travel_mm: dict[str, tuple[float, float]]) -> list[str]: ...


def known_controllers() -> dict[str, str]:
    """Name -> ``module:attribute`` for every built-in and installed post-processor."""
    known = dict(BUILTIN)
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        known.setdefault(ep.name, ep.value)
    return known


def get_postprocessor(name: str) -> PostProcessor:
    known = known_controllers()
    if name not in known:
        raise UnknownControllerError(name, list(known))
    module, _, attr = known[name].partition(":")
    return getattr(import_module(module), attr)()


def check_controllers(config: Config) -> None:
    """Every controller ``post.controllers`` names must be registered: a
    :class:`~sdit_path.errors.ConfigError` naming the file, the line and the known names
    otherwise (the registry is the one source of names)."""
    known = known_controllers()
    for name in config.post.controllers:
        if name not in known:
            raise Reader(config.source, config.text).fail(
                "post.controllers", f"unknown controller {short(name)}; known controllers: "
                                    f"{', '.join(sorted(known))}")
