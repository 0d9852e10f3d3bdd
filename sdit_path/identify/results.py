"""What an identification determines: frozen, with ``to_json()``."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

from ..arrays import ReadOnlyDict


@dataclass(frozen=True, slots=True)
class Identification:
    """The geometry a set of recordings determines, and no more.

    ``combinations``: the determined combinations of the model's parameters (each with
    its terms, estimate and standard uncertainty, k=1); ``identifiable_parameters``: the
    parameters determined one by one; ``not_individually_identifiable``: the rest;
    ``model_state``: the fitted model (minimum norm: what the data do not determine held
    at zero), to simulate the readings it predicts, not machine errors one by one;
    ``nuisances``: per recording, the set-up (centring, bar length) and the effects'
    columns fitted beside; ``rank``, ``determined``: the data's structural rank and how
    many combinations it determines within the model's prior magnitudes;
    ``figures``: squareness and scale mismatch as a ballbar reads them
    (:mod:`sdit_path.identify.figures`), each with its estimate and standard uncertainty
    where the data determine it, else the parameters it would need;
    ``noise_std_um``, ``residual_rms_um``: what the fit leaves; ``uncertainty``: how the
    uncertainties are made; ``exact_chain``: the Gauss-Newton steps on the exact error
    chain; ``observability``: per layer and segment, its share of the determined
    subspace.  Optional: ``aliasing`` (effects that take certainty from a combination),
    ``prior_estimates``, ``asked`` (what would make a parameter asked for identifiable),
    and, where the recordings were aligned first, ``recordings`` and ``warnings``."""

    model: Mapping
    samples: int
    experiments: tuple
    noise_std_um: float
    residual_rms_um: float
    rank: int
    determined: int
    uncertainty: Mapping
    exact_chain: Mapping
    combinations: tuple
    identifiable_parameters: tuple
    model_state: Mapping
    not_individually_identifiable: tuple
    nuisances: tuple
    observability: Mapping
    figures: tuple = ()
    aliasing: tuple | None = None
    prior_estimates: tuple | None = None
    asked: tuple | None = None
    recordings: tuple | None = None
    warnings: tuple | None = None

    @classmethod
    def from_parts(cls, **parts) -> "Identification":
        return cls(**{k: _frozen(v) for k, v in parts.items()})

    def with_recordings(self, recordings: list[dict], warnings: list[str]) -> "Identification":
        """The identification with the recordings it was made from (as aligned) and the
        warnings they give."""
        return dataclasses.replace(self, recordings=_frozen(recordings),
                                   warnings=_frozen(warnings))

    def to_json(self) -> dict:
        out = {}
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if value is not None or f.default is not None:
                out[f.name] = _thawed(value)
        return out


def _frozen(value):
    if isinstance(value, Mapping):
        return ReadOnlyDict({k: _frozen(v) for k, v in value.items()})
    if isinstance(value, (list, tuple)):
        return tuple(_frozen(v) for v in value)
    return value


def _thawed(value):
    if isinstance(value, Mapping):
        return {k: _thawed(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_thawed(v) for v in value]
    return value
