"""The diagnosis' settings."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Options:
    """``heldout_every``: one in n stretches of each kind is held out (``held_stretches``);
    ``max_fit_samples``: samples used for fitting (a seeded choice of 0.5 s blocks);
    ``min_heldout_gain``: relative held-out MSE drop a new effect must bring;
    (the noise threshold below scales with the share of samples the effect acts on)
    ``bic_margin``: extra BIC units an effect must win; ``min_effect_noise``: the
    held-out mean square it explains must exceed (this x noise)^2; ``mimic_r2``: share of a
    finding's signal another effect must reproduce to be reported as its mimic;
    ``max_rate_hz``: a recording sampled faster is read at every n-th sample, n the
    largest that keeps this rate (500 Hz keeps every reversal and dwell and modes up to
    the library's 250 Hz, and halves the time of a 1 kHz recording); None reads all."""

    heldout_every: int = 3
    max_fit_samples: int = 300_000
    min_heldout_gain: float = 0.01
    bic_margin: float = 10.0
    mimic_r2: float = 0.8
    min_effect_noise: float = 0.35
    max_effects: int = 6
    max_rate_hz: float | None = None
