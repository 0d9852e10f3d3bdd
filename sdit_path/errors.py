"""One small hierarchy of typed errors for bad input.

Every message says what was expected, what arrived and where (file, line, field,
segment id).  The CLI maps each class to an exit code and prints one line.
Expected outcomes that are not bugs (an unreachable pose, a collision) are result
values, not exceptions.
"""

from __future__ import annotations


class SditError(Exception):
    """Base class of every error sdit-path raises on purpose."""

    exit_code = 1


class ConfigError(SditError):
    """A configuration file cannot be parsed or holds an invalid value.

    ``where`` names the file and, when known, the line or the dotted key.
    """

    exit_code = 2

    def __init__(self, where: str, message: str):
        self.where = where
        self.message = message
        super().__init__(f"{where}: {message}")


class PlanError(SditError):
    """A valid configuration that cannot be planned (for example out of travel).

    ``details`` holds one line per offending piece, printed under the message."""

    exit_code = 3

    def __init__(self, message: str, details: list[str] | None = None):
        super().__init__(message)
        self.details = list(details or [])


class LintError(SditError):
    """An NC program failed its lint; it was not written."""

    exit_code = 4

    def __init__(self, program: str, problems: list[str]):
        self.program = program
        self.problems = list(problems)
        shown = "; ".join(self.problems[:3])
        more = f" (+{len(self.problems) - 3} more)" if len(self.problems) > 3 else ""
        super().__init__(f"{program}: NC lint failed: {shown}{more}")


class UnknownControllerError(SditError):
    """A post-processor name that is not registered."""

    exit_code = 2

    def __init__(self, name: str, known: list[str], where: str = "post.controllers"):
        self.name = name
        self.known = sorted(known)
        super().__init__(
            f"{where}: unknown controller {name!r}; known controllers: {', '.join(self.known)}"
        )


class OutputError(SditError):
    """The output location cannot be used (not empty without --force, not writable)."""

    exit_code = 5


class RecordingError(SditError):
    """A readable recording that does not fit the program it is given with (shorter or
    far longer than the program, too few readings where the program runs, no alignment
    found)."""

    exit_code = 6
