"""The bundled sample configurations, in the installed package or the checkout."""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from ..errors import ConfigError

#: The bundled default sample, planned when the CLI is given no config.
DEFAULT_SAMPLE = "vmc_3axis.toml"


def bundled_samples() -> list[str]:
    """File names of the bundled sample configurations."""
    return sorted(p.name for p in sample_path(DEFAULT_SAMPLE).parent.glob("*.toml"))


def sample_path(name: str) -> Path:
    """Path of a bundled sample, in the installed package or the source checkout."""
    installed = resources.files("sdit_path") / "samples" / name
    if installed.is_file():
        return Path(str(installed))
    checkout = Path(__file__).resolve().parents[2] / "samples" / name
    if checkout.is_file():
        return checkout
    raise ConfigError(name, "bundled sample not found; the installation is incomplete")
