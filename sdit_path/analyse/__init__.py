"""From a test's recordings to one answer (``sdit-path analyse``): each recording
matched to its program and aligned (``matching``), diagnosed, and the geometry
identified from all of them with the effects found (``run``)."""

from .matching import match
from .results import Analysed, AnalysisResult
from .run import DIAGNOSIS, analyse

__all__ = ["DIAGNOSIS", "Analysed", "AnalysisResult", "analyse", "match"]
