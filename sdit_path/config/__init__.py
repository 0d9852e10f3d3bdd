"""The configuration: pure data read from one TOML file (model, reader, parse, samples).

Imports nothing of the package but :mod:`sdit_path.errors`; what only a later stage can
judge (a controller's name, the pivot within reach) is checked by
:func:`sdit_path.plan.configure.check_config`.
"""

from .model import (AXIS_NAMES, CREST_RANGE, FIVE_AXIS_MODES, PASSES, PROJECTIONS, SCHEDULES,
                    SHAPES, TILT_OFFSET_MAX_DEG, TIMING_CONTROLS, TRANSITS, Axis, BallbarConfig, CheckConfig,
                    Config, CurveConfig, MachineConfig, PostConfig, RotaryConfig, SceneConfig,
                    ScenePart, SectorCurve, TestConfig, TimingConfig)
from .parse import load_config, parse_config
from .reader import Reader
from .samples import DEFAULT_SAMPLE, bundled_samples, sample_path

__all__ = ["AXIS_NAMES", "CREST_RANGE", "DEFAULT_SAMPLE", "FIVE_AXIS_MODES", "PASSES",
           "PROJECTIONS", "SCHEDULES", "SHAPES", "TILT_OFFSET_MAX_DEG", "TIMING_CONTROLS",
           "TRANSITS", "Axis",
           "BallbarConfig", "CheckConfig", "Config", "CurveConfig", "MachineConfig",
           "PostConfig", "Reader", "RotaryConfig", "SceneConfig", "ScenePart", "SectorCurve",
           "TestConfig", "TimingConfig", "bundled_samples", "load_config", "parse_config",
           "sample_path"]
