"""Seeded mutations of what users hand the tool (a configuration, a recording): the
hostile-input campaign (``hostile_campaign.py``) and the hostile-input tests draw from here."""

from __future__ import annotations

import random
import re

_WEIRD = ["0", "-1", "1e308", "-1e308", "5e-324", "nan", "inf", "-inf", "1e-300", '"x"', '""',
          "[]", "[1]", "[1, 2, 3, 4]", "{}", "true", '"中文"', '"\\u0000"', "[[1]]", "1_000",
          '"' + "y" * 2000 + '"', "-0.0", "3", "[0, 0, 0]", "[1e300, 1e300, 1e300]"]


def mutate_config(text: str, rng: random.Random) -> str:
    """``text`` (TOML) with one to three seeded edits: odd values, a line dropped, a
    misspelt key, a line cut short, a stray table or mark."""
    lines = text.splitlines()
    for _ in range(rng.randint(1, 3)):
        assignable = [i for i, ln in enumerate(lines) if re.match(r"^\s*[A-Za-z_]+\s*=", ln)]
        op = rng.random()
        i = rng.choice(assignable)
        key = lines[i].split("=", 1)[0].strip()
        if op < 0.6:
            lines[i] = f"{key} = {rng.choice(_WEIRD)}"
        elif op < 0.7:
            del lines[i]
        elif op < 0.8:
            lines.insert(i, f"{key}_typo = 1")
        elif op < 0.9:
            j = rng.randrange(len(lines))
            lines[j] = lines[j][: rng.randrange(len(lines[j]) + 1)]
        else:
            lines.insert(rng.randrange(len(lines)), rng.choice(
                ["[machine]", "[[scene.parts]]", "# Fräsmaschine ✓", "\ufeff", "x = ", "[test"]))
    return "\n".join(lines) + "\n"


def mutate_trace(text: str, rng: random.Random) -> str:
    """``text`` (a recording's CSV) with one to three seeded edits: a line cut, dropped,
    swapped or extended, an odd value, a stray line, another separator."""
    lines = text.splitlines()
    for _ in range(rng.randint(1, 3)):
        i = rng.randrange(len(lines))
        op = rng.random()
        if op < 0.25:
            lines[i] = lines[i][: rng.randrange(len(lines[i]) + 1)]
        elif op < 0.4:
            del lines[i]
        elif op < 0.55:
            lines[i] = lines[i] + rng.choice([",", ";", "\t", ",1", '"', ",,"])
        elif op < 0.7:
            parts = lines[i].split(",")
            parts[rng.randrange(len(parts))] = rng.choice(
                ["", "nan", "inf", "-1e308", "x", "1,5", "１２", "0x10", "1e999", '"3"'])
            lines[i] = ",".join(parts)
        elif op < 0.8:
            j = rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
        elif op < 0.9:
            lines.insert(i, rng.choice(["# x: y", "", "t_s,delta_l_um", "\ufeff", "#"]))
        else:
            lines = [ln.replace(",", ";") for ln in lines]
    return "\n".join(lines) + "\n"


_NUMBER = r"(?<![\w.])-?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?"


def mutate_numbers(text: str, rng: random.Random) -> str:
    """Scale one to three numbers of the config by 10^U(-3, 3), sometimes flipping the
    sign: mostly plausible configs that reach the planner's corners."""
    lines = text.splitlines()
    for _ in range(rng.randint(1, 3)):
        cand = [i for i, ln in enumerate(lines)
                if "=" in ln and not ln.lstrip().startswith("#") and re.search(_NUMBER, ln)]
        i = rng.choice(cand)
        key, value = lines[i].split("=", 1)
        value = value.split("#", 1)[0]
        matches = list(re.finditer(_NUMBER, value))
        m = rng.choice(matches)
        x = float(m.group(0)) * 10 ** rng.uniform(-3, 3) * (-1 if rng.random() < 0.15 else 1)
        new = f"{x:.6g}" if "." in m.group(0) or "e" in m.group(0) else str(int(round(x)))
        if "." not in new and "e" not in new and "." in m.group(0):
            new += ".0"
        lines[i] = key + "=" + value[:m.start()] + new + value[m.end():]
    return "\n".join(lines) + "\n"
