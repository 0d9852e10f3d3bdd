"""Neutralising user text so it can never become an NC block."""

from __future__ import annotations

import re
import unicodedata


def neutralise(text: str, forbidden: str = "") -> str:
    """One printable ASCII line: control and separator characters become spaces,
    accents are dropped, other non-ASCII becomes ``?`` and every character in
    ``forbidden`` (a controller's comment delimiters) becomes ``_``."""
    text = unicodedata.normalize("NFKD", str(text))
    out = []
    for ch in text:
        cat = unicodedata.category(ch)
        if cat == "Mn":  # combining accent left by NFKD
            continue
        if cat[0] in "CZ" or ch in "\r\n\t\v\f\x85\u2028\u2029":
            out.append(" ")
        elif ord(ch) > 126:
            out.append("?")
        elif ch in forbidden:
            out.append("_")
        else:
            out.append(ch)
    return re.sub(r" {2,}", " ", "".join(out)).strip()


def program_name(prefix: str, layer: str, max_length: int = 24) -> str:
    """A program name that every supported controller accepts: ``[A-Z][A-Z0-9_]*``."""
    base = re.sub(r"[^A-Z0-9_]", "_", neutralise(prefix).upper()) or "SDIT"
    if not base[0].isalpha():
        base = "P" + base
    suffix = f"_{layer}"
    return base[: max_length - len(suffix)] + suffix
