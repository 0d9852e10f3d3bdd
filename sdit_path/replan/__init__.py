"""Re-planning bad segments (the paper's D3): find them, say why, replace their sector's
curves, and write the re-planned plan.

``evaluate`` reviews a plan segment by segment; ``candidates`` proposes curves for a
sector and chooses among them; ``setup`` tries set-up changes where no curve helps;
``run`` does the whole re-plan and holds its result."""

from .evaluate import Limits, Reason, Review
from .run import Replan, analysis_reasons, replan

__all__ = ["Limits", "Reason", "Replan", "Review", "analysis_reasons", "replan"]
