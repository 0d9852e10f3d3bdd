"""Diagnosing the gap between a simulated and a measured ballbar trace.

``orchestration`` runs it; ``align`` and ``timing`` read the recording's timing;
``heldout``, ``selection`` and ``readout`` choose and read out the effects of the
library (``effects``); ``ambiguity`` says what the recording cannot tell apart;
``results`` holds what comes out."""

from .options import Options
from .orchestration import diagnose
from .results import Diagnosis, Finding

__all__ = ["Diagnosis", "Finding", "Options", "diagnose"]
