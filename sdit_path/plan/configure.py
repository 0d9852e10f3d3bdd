"""A configuration checked by every stage that judges part of it.

:mod:`sdit_path.config` reads what the file alone decides; a controller's name is the
post-processor registry's to judge and the pivot's reach the kinematic chain's.  Every
command that plans (and every reader of a plan) takes its configuration from here."""

from __future__ import annotations

from pathlib import Path

from .. import config as _config
from ..config import Config
from ..machine.reach import check_pivot
from ..nc.registry import check_controllers


def check_config(config: Config) -> Config:
    """``config`` after the stages' own checks (each a
    :class:`~sdit_path.errors.ConfigError` naming the file, the line and the key)."""
    check_controllers(config)
    check_pivot(config)
    return config


def parse_config(text: str, source: str = "<config>") -> Config:
    """:func:`sdit_path.config.parse_config`, then :func:`check_config`."""
    return check_config(_config.parse_config(text, source))


def load_config(path: str | Path | None = None) -> Config:
    """:func:`sdit_path.config.load_config` (the bundled default sample when ``path`` is
    None), then :func:`check_config`."""
    return check_config(_config.load_config(path))
