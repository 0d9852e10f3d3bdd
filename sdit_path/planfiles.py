"""Reading a plan directory written by ``sdit-path plan``: its config, manifest and
trajectories (what the simulator, the identification and the diagnosis start from)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from .config import Config, parse_config
from .errors import ConfigError
from .timing.trajectory import Samples, read_csv_file


@dataclass(frozen=True, slots=True)
class PlanFiles:
    directory: Path
    config: Config
    manifest: dict

    @property
    def program_names(self) -> list[str]:
        return sorted({p["name"] for p in self.manifest["programs"]})

    def trajectory(self, program: str) -> Samples:
        entry = next((p for p in self.manifest["programs"] if p["name"] == program), None)
        if entry is None:
            raise ConfigError(str(self.directory),
                              f"no program {program!r}; programs: {', '.join(self.program_names)}")
        if not entry.get("trajectory"):
            raise ConfigError(str(self.directory), f"{program}: no trajectory was exported "
                                                   f"(timing.export_trajectories = false)")
        path = self.directory / entry["trajectory"]
        if not path.is_file():
            raise ConfigError(str(path), "trajectory file missing from the plan directory")
        try:
            return read_csv_file(path)
        except FileNotFoundError:
            raise ConfigError(str(path), "trajectory file missing from the plan directory") from None

    def tested_travel(self) -> dict[str, tuple[float, float]]:
        return {k: (v[0], v[1]) for k, v in self.manifest.get("tested_travel", {}).items()}


def load_plan(directory: str | Path) -> PlanFiles:
    d = Path(directory)
    try:
        manifest = json.loads((d / "plan.json").read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(str(d), "not a plan directory (no plan.json); run sdit-path plan first") from None
    except json.JSONDecodeError as exc:
        raise ConfigError(str(d / "plan.json"), f"line {exc.lineno}: not valid JSON") from None
    try:
        text = (d / "config.toml").read_text(encoding="utf-8")
    except FileNotFoundError:
        raise ConfigError(str(d), "config.toml missing from the plan directory") from None
    return PlanFiles(d, parse_config(text, str(d / "config.toml")), manifest)
