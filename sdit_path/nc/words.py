"""Number formatting, word parsing and template framing shared by the post-processors."""

from __future__ import annotations

import math
import re
from functools import lru_cache
from importlib import resources
from pathlib import Path

import jinja2


def fixed(value: float, decimals: int) -> str:
    """Fixed-point text with ``decimals`` places and never ``-0.000``."""
    if not math.isfinite(value):
        return repr(value)  # 'nan' / 'inf': the lint rejects it
    text = f"{value:.{decimals}f}"
    if text.startswith("-") and float(text) == 0.0:
        text = text[1:]
    return text


def trimmed(value: float, decimals: int = 4) -> str:
    """Shortest fixed-point text up to ``decimals`` places: 600 -> '600', 2.5 -> '2.5'."""
    text = fixed(value, decimals)
    if "." in text:
        text = text.rstrip("0").rstrip(".")
    return text


def xyz(point, decimals: int) -> str:
    """``X.. Y.. Z..`` words of a point, fixed decimals."""
    return " ".join(f"{a}{fixed(v, decimals)}" for a, v in zip("XYZ", point))


def count_blocks(text: str) -> int:
    """NC blocks of a program: lines with code, not comment-only lines or ``%``."""
    return sum(1 for line in text.splitlines()
               if line.strip() and not line.lstrip().startswith((";", "(", "%")))


WORD = re.compile(r"([A-Z]+)(=?)([-+]?(?:\d+\.?\d*|\.\d+))")


def words(code: str) -> tuple[list[tuple[str, str, str]], list[str]]:
    """Split block code into ``(address, '=', number text)`` words and unparseable tokens."""
    good, bad = [], []
    for tok in code.split():
        m = WORD.fullmatch(tok)
        if m:
            good.append((m.group(1), m.group(2), m.group(3)))
        elif re.fullmatch(r"[A-Z]+", tok):
            good.append((tok, "", ""))
        else:
            bad.append(tok)
    return good, bad


def templates_dir() -> Path:
    return Path(str(resources.files("sdit_path") / "templates"))


@lru_cache(maxsize=None)
def _environment() -> jinja2.Environment:
    return jinja2.Environment(
        loader=jinja2.FileSystemLoader(str(templates_dir())),
        undefined=jinja2.StrictUndefined,
        keep_trailing_newline=True,
        trim_blocks=True,
        lstrip_blocks=True,
        autoescape=False,
    )


def frame(template: str, **context) -> str:
    """Render a framing template (header, preamble, body lines, footer)."""
    return _environment().get_template(template).render(**context)
