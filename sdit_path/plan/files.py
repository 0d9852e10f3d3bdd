"""Reading a plan directory written by ``sdit-path plan``: its config, manifest and
trajectories (what the simulator, the identification and the diagnosis start from).

A plan directory is checked before anything is read from it: ``plan.json`` must be
the manifest of a plan, every file it names must lie inside the directory, and every
file must still have the sha256 fingerprint it was written with, so that an edited
config, a swapped trajectory or a hand-edited program is refused by name instead of
being read as the plan.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass, field, fields, replace
from pathlib import Path, PurePosixPath

import numpy as np

from ..config import Config
from ..errors import ConfigError
from ..timing.trajectory import Samples
from .configure import parse_config
from .trajectory_csv import read_csv_file

FORMAT = "sdit-path/plan"


@dataclass(frozen=True, slots=True)
class PlanFiles:
    directory: Path
    config: Config
    manifest: dict
    #: which controller's programs the recordings come from (None: the first the plan
    #: lists); the expected reading follows the program as written for it
    controller: str | None = None
    #: the control whose own motion of the programs as written the trajectories are
    #: (None: the plan's own trajectories, to which the program as written adds its
    #: geometry); see :attr:`control_motion`
    motion: str | None = None
    #: per program, the timing its recording showed (``(program, motion, retiming)``:
    #: the control whose motion it re-times, None for the plan's trajectory, and the
    #: :class:`~sdit_path.timing.retime.Retiming`); see :meth:`timed_as_recorded`
    retimed: tuple = ()
    #: trajectories read so far (each file is read and checked once per loaded plan;
    #: its arrays are read-only)
    _read: dict = field(default_factory=dict, compare=False, repr=False)

    @classmethod
    def in_memory(cls, config: Config, program: str, samples: Samples) -> "PlanFiles":
        """A plan of one program whose trajectory is ``samples`` (not read from files):
        to study a design before it is written."""
        plan = cls(None, config, {"programs": [{"name": program}]})
        plan._read[program] = samples
        return plan

    @property
    def program_names(self) -> list[str]:
        return sorted({p["name"] for p in self.manifest["programs"]})

    @property
    def control_motion(self) -> bool:
        """Whether the trajectories are a control's motion of the programs as written
        rather than the plan's: recordings of LinuxCNC (``--controller linuxcnc``) of a
        plan timed by our jerk-limited model, or ``perturb --control``.  The control's planner
        (:mod:`~sdit_path.timing.linuxcnc_tp`) gives its ramps, blends and slow-downs,
        which on a 5-axis program take up to twice the planned time per run."""
        return self.directory is not None and self.motion is not None

    def planned(self) -> "PlanFiles":
        """This plan with its own trajectories (not the control's motion, nor the timing
        of a recording)."""
        if self.motion or self.retimed:
            return replace(self, controller=None, motion=None, retimed=(), _read={})
        return self

    def motion_of(self, program: str) -> str | None:
        """The control whose motion of the program as written ``program``'s trajectory
        is (None: the plan's trajectory, to which the program as written adds its
        geometry)."""
        for name, motion, _ in self.retimed:
            if name == program:
                return motion if self.directory is not None else None
        return self.motion if self.directory is not None else None

    def timed_as_recorded(self, program: str, motion: str | None, retiming) -> "PlanFiles":
        """This plan with ``program``'s trajectory the plan's (``motion`` None) or
        ``motion``'s motion of it, re-timed run by run as its recording showed
        (:func:`~sdit_path.timing.retime.retime`)."""
        kept = tuple(r for r in self.retimed if r[0] != program)
        return replace(self, retimed=kept + ((program, motion, retiming),),
                       _read={k: v for k, v in self._read.items() if k != program}
                       if motion == self.motion else {})

    def retiming(self, program: str):
        """``program``'s :class:`~sdit_path.timing.retime.Retiming`, or None."""
        return next((r for name, _, r in self.retimed if name == program), None)

    def moved_by(self, control: str) -> "PlanFiles":
        """This plan with every program's trajectory the motion of ``control`` running
        the program as written (:mod:`.control_motion`)."""
        return replace(self, motion=control, _read={})

    def let_go(self) -> None:
        """Forget the trajectories read from their files (each is read again when asked,
        in a fraction of a second; a hundred MB of them lay in memory through a whole
        analysis); computed ones (a control's motion, a re-timing: minutes each) stay."""
        for program in list(self._read):
            if self.motion_of(program) is None and self.retiming(program) is None \
                    and self.directory is not None:
                del self._read[program]

    def trajectory(self, program: str) -> Samples:
        if program not in self._read:
            motion = self.motion_of(program)
            if motion is not None:
                from .control_motion import control_samples

                samples = control_samples(self.planned(), program, motion)
            else:
                samples = self._load_trajectory(program)
            if self.retiming(program) is not None:
                from ..timing.retime import retime

                samples = retime(samples, self.retiming(program))
            for f in fields(samples):
                value = getattr(samples, f.name)
                if isinstance(value, np.ndarray):
                    value.setflags(write=False)
            self._read[program] = samples
        return self._read[program]

    def _load_trajectory(self, program: str) -> Samples:
        entry = next((p for p in self.manifest["programs"] if p["name"] == program), None)
        if entry is None:
            raise ConfigError(str(self.directory),
                              f"no program {program!r}; programs: {', '.join(self.program_names)}")
        if not entry.get("trajectory"):
            raise ConfigError(str(self.directory), f"{program}: no trajectory was exported "
                                                   f"(timing.export_trajectories = false)")
        path = _inside(self.directory, entry["trajectory"], "programs[].trajectory")
        if not path.is_file():
            raise ConfigError(str(path), "trajectory file missing from the plan directory")
        _check_fingerprint(self.directory, self.manifest, entry["trajectory"])
        samples = read_csv_file(path)
        _check_samples(samples, str(path), self.config)
        _check_program(path, entry, samples)
        return samples

    @property
    def controllers(self) -> list[str]:
        """The controllers the plan wrote programs for, in the config's order."""
        written = {p.get("controller") for p in self.manifest["programs"]}
        return [c for c in self.config.post.controllers if c in written]

    def for_controller(self, name: str | None) -> "PlanFiles":
        """This plan, its recordings taken as runs of ``name``'s programs (None: the
        first controller the plan lists): the expected reading follows the program as
        written for it and, for LinuxCNC, the control's own timing
        (:attr:`control_motion`).  Refuses a controller it has no programs for."""
        if name is None:
            return self
        if name not in self.controllers:
            raise ConfigError(str(self.directory), f"no programs for controller {name!r}; "
                                                   f"this plan has {', '.join(self.controllers)}")
        if name == "linuxcnc" and self.config.timing.control != "linuxcnc":
            return replace(self.moved_by(name), controller=name)
        return replace(self, controller=name, _read=self._read)

    @property
    def ran_on(self) -> str | None:
        """The controller whose programs the recordings come from."""
        return self.controller or next(iter(self.controllers), None)

    def program_text(self, program: str) -> tuple[str, dict] | None:
        """The text of ``program`` as written for :attr:`ran_on`, fingerprint-checked,
        and its plan.json entry (None for a plan held in memory)."""
        if self.directory is None:
            return None
        entry = next((p for p in self.manifest["programs"] if p["name"] == program
                      and p.get("controller") == self.ran_on), None)
        if entry is None:
            raise ConfigError(str(self.directory), f"no {self.ran_on} program {program!r}")
        path = _inside(self.directory, entry.get("file"), "programs[].file")
        _check_fingerprint(self.directory, self.manifest, entry["file"])
        try:
            return path.read_text(encoding="utf-8"), entry
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(str(path), f"cannot read the program: {exc}") from None

    def tested_travel(self) -> dict[str, tuple[float, float]]:
        return {k: (v[0], v[1]) for k, v in self.manifest.get("tested_travel", {}).items()}


def _inside(directory: Path, rel, field: str) -> Path:
    """``directory / rel`` for a relative path that stays inside ``directory``."""
    where = str(directory / "plan.json")
    if not isinstance(rel, str) or not rel:
        raise ConfigError(where, f"{field}: expected a file name inside the plan directory, "
                                 f"got {rel!r}")
    p = PurePosixPath(rel)
    if p.is_absolute() or ".." in p.parts or "\\" in rel or ":" in p.parts[0]:
        raise ConfigError(where, f"{field}: {rel!r} points outside the plan directory; refused")
    path = directory / p
    try:
        if not path.resolve().is_relative_to(directory.resolve()):
            raise ConfigError(where, f"{field}: {rel!r} leads outside the plan directory "
                                     f"(symbolic link); refused")
    except OSError:
        pass
    return path


def _check_fingerprint(directory: Path, manifest: dict, rel: str) -> None:
    """The file's sha256 must be the one plan.json recorded (plans written before
    fingerprints existed have no ``files`` table and are read as they are)."""
    files = manifest.get("files")
    if files is None:
        return
    expected = files.get(rel)
    path = directory / rel
    if expected is None:
        raise ConfigError(str(path), "not listed in plan.json's fingerprints; the plan "
                                     "directory was changed after planning")
    digest = hashlib.sha256()
    try:
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                digest.update(block)
    except OSError as exc:
        raise ConfigError(str(path), f"cannot read: {exc.strerror}") from None
    if digest.hexdigest() != expected:
        raise ConfigError(str(path), "changed since it was planned (its sha256 differs from "
                                     "plan.json's); plan again instead of editing a plan")


def _check_samples(s: Samples, source: str, config: Config) -> None:
    import numpy as np

    n = len(s.t_s)
    if n < 2:
        raise ConfigError(source, f"trajectory has {n} sample(s); expected a timed program")
    # each array on its own (stacked, an hour's numbers were a copy of 0.24 GB)
    bad = [int(np.argwhere(~np.isfinite(a))[0, 0])
           for a in (s.t_s, s.ball_mm, s.axes, s.speed_mm_per_s) if not np.all(np.isfinite(a))]
    if bad:
        raise ConfigError(source, f"data row {min(bad) + 1}: not a finite number; the "
                                  f"trajectory is damaged")
    if not np.all(np.diff(s.t_s) > 0):
        row = int(np.argmax(~(np.diff(s.t_s) > 0))) + 2
        raise ConfigError(source, f"data row {row}: time does not increase; the trajectory "
                                  f"is damaged")
    expected = tuple(a.name for a in config.machine.axes)
    if tuple(sorted(s.axis_names)) != tuple(sorted(expected)):
        raise ConfigError(source, f"axis columns {', '.join(s.axis_names) or 'none'}; the "
                                  f"plan's machine has {', '.join(expected)}")


def _header_lines(path: Path) -> dict[str, str]:
    """The ``# key: value`` lines at the top of a (possibly gzip-compressed) trajectory."""
    import gzip

    opener = gzip.open if path.suffix == ".gz" else open
    out = {}
    try:
        with opener(path, "rt", encoding="utf-8", errors="replace") as fh:
            for line in fh:
                if not line.startswith("#"):
                    break
                key, _, value = line[1:].partition(":")
                out[key.strip()] = value.strip()
    except (OSError, EOFError):
        pass
    return out


def _check_program(path: Path, entry: dict, s: Samples) -> None:
    """The trajectory is the whole timed program the manifest names."""
    head = _header_lines(path)
    if head.get("program", entry["name"]) != entry["name"]:
        raise ConfigError(str(path), f"holds the trajectory of {head.get('program')!r}, not of "
                                     f"{entry['name']!r}; the plan directory was changed")
    cycle = entry.get("cycle_time_s")
    if isinstance(cycle, (int, float)) and not isinstance(cycle, bool):
        step = float(s.t_s[1] - s.t_s[0])
        if not abs(float(s.t_s[-1]) - cycle) <= 2 * step + 1e-3:
            raise ConfigError(str(path), f"ends at {float(s.t_s[-1]):.3f} s, but the program "
                                         f"{entry['name']} lasts {cycle:.3f} s; the trajectory "
                                         f"is cut or damaged")


#: plan.json's own fingerprint: the sha256 of the rest of it in canonical JSON
SEAL = "sealed_sha256"


def seal_digest(manifest: dict) -> str:
    """The sha256 of ``manifest`` without its seal, as canonical JSON (sorted keys, no
    spaces): any edit of plan.json changes it, its formatting does not."""
    rest = {k: v for k, v in manifest.items() if k != SEAL}
    text = json.dumps(rest, sort_keys=True, separators=(",", ":"), ensure_ascii=False,
                      allow_nan=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


def sealed(manifest: dict) -> dict:
    """``manifest`` with its seal, last."""
    rest = {k: v for k, v in manifest.items() if k != SEAL}
    return {**rest, SEAL: seal_digest(rest)}


def _check_seal(m: dict, where: str) -> None:
    said = m.get(SEAL)
    if not isinstance(said, str):
        raise ConfigError(where, "carries no seal (its own sha256): written by an older "
                                 "sdit-path or edited; plan again")
    if seal_digest(m) != said:
        raise ConfigError(where, "changed since it was planned (its own sha256 differs from "
                                 "its seal); plan again instead")


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def _against_config(m: dict, cfg: Config, where: str) -> None:
    """plan.json's values that later stages read, checked against the config they were
    planned from (itself fingerprinted): a sealed but inconsistent manifest is refused."""
    linear = {a.name: a for a in cfg.machine.axes if not a.is_rotary}
    travel = m["tested_travel"]
    for name, (lo, hi) in travel.items():
        axis = linear.get(name)
        if axis is None:
            raise ConfigError(where, f"tested_travel: {str(name)[:20]!r} is not a linear axis of "
                                     f"the machine ({', '.join(linear)})")
        if not (_finite(lo) and _finite(hi) and lo < hi):
            raise ConfigError(where, f"tested_travel.{name}: expected [min, max] with min < max, "
                                     f"got [{lo}, {hi}]")
        a_lo, a_hi = axis.travel
        if lo < a_lo - 1e-6 or hi > a_hi + 1e-6:
            raise ConfigError(where, f"tested_travel.{name}: [{lo:g}, {hi:g}] leaves the axis' "
                                     f"travel [{a_lo:g}, {a_hi:g}]")
    missing = set(linear) - set(travel)
    if missing:
        raise ConfigError(where, f"tested_travel: lacks {', '.join(sorted(missing))}")
    sphere = m.get("sphere")
    if sphere is not None:
        centre, radius = sphere.get("centre_mm"), sphere.get("radius_mm")
        if not (isinstance(centre, list) and len(centre) == 3 and all(map(_finite, centre))
                and _finite(radius)):
            raise ConfigError(where, "sphere: expected centre_mm [x, y, z] and radius_mm, "
                                     "finite numbers")
        if (abs(radius - cfg.ballbar.bar_length_mm) > 1e-6 or any(
                abs(c - p) > 1e-6 for c, p in zip(centre, cfg.ballbar.pivot_mm))):
            raise ConfigError(where, "sphere: differs from the config's pivot and bar length")


def _manifest_shape(m, where: str) -> dict:
    if not isinstance(m, dict) or m.get("format") != FORMAT:
        raise ConfigError(where, f"not a plan manifest (expected a JSON object with "
                                 f"\"format\": \"{FORMAT}\")")
    programs = m.get("programs")
    if not isinstance(programs, list) or not all(
            isinstance(p, dict) and isinstance(p.get("name"), str)
            and (p.get("trajectory") is None or isinstance(p.get("trajectory"), str))
            for p in programs):
        raise ConfigError(where, "programs: expected a list of {name, trajectory, ...} objects")
    if not programs:
        raise ConfigError(where, "programs: the plan holds no program")
    travel = m.get("tested_travel")
    if not isinstance(travel, dict) or not travel or not all(
            isinstance(v, list) and len(v) == 2
            and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
            and v[0] <= v[1] for v in travel.values()):
        raise ConfigError(where, "tested_travel: expected {axis: [min, max]} for every "
                                 "linear axis")
    files = m.get("files")
    if files is not None and not (isinstance(files, dict) and all(
            isinstance(k, str) and isinstance(v, str) for k, v in files.items())):
        raise ConfigError(where, "files: expected {relative path: sha256}")
    return m


def load_plan(directory: str | Path) -> PlanFiles:
    d = Path(directory)
    where = str(d / "plan.json")
    if not d.is_dir():
        raise ConfigError(str(d), "not a directory; expected a folder written by sdit-path plan")
    try:
        manifest = json.loads((d / "plan.json").read_bytes().decode("utf-8"))
    except FileNotFoundError:
        raise ConfigError(str(d), "not a plan directory (no plan.json); run sdit-path plan first") from None
    except IsADirectoryError:
        raise ConfigError(where, "is a directory; expected the plan's manifest") from None
    except OSError as exc:
        raise ConfigError(where, f"cannot read: {exc.strerror}") from None
    except UnicodeDecodeError:
        raise ConfigError(where, "not UTF-8 text; expected the plan's manifest") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(where, f"line {exc.lineno}: not valid JSON") from None
    _manifest_shape(manifest, where)
    _check_seal(manifest, where)
    cfg_path = d / "config.toml"
    try:
        raw = cfg_path.read_bytes()
    except FileNotFoundError:
        raise ConfigError(str(d), "config.toml missing from the plan directory") from None
    except OSError as exc:
        raise ConfigError(str(cfg_path), f"cannot read: {exc.strerror}") from None
    if manifest.get("files") is not None:
        _check_fingerprint(d, manifest, "config.toml")
    else:
        recorded = (manifest.get("config") or {}).get("sha256")
        if isinstance(recorded, str) and hashlib.sha256(raw).hexdigest() != recorded:
            raise ConfigError(str(cfg_path), "changed since it was planned (its sha256 differs "
                                             "from plan.json's); plan again instead")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError:
        raise ConfigError(str(cfg_path), "not UTF-8 text") from None
    cfg = parse_config(text, str(cfg_path))
    _against_config(manifest, cfg, where)
    return PlanFiles(d, cfg, manifest)
