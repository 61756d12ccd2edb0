"""Errors a user can act on. Each names the field (or file) and the fix; never shown as a traceback."""
from __future__ import annotations

from dataclasses import dataclass


class DataPipeError(Exception):
    """A problem the user can fix (bad input, missing file, refused output folder)."""


class OutputStateError(DataPipeError):
    """The output folder's state (a lock, a corrupt or foreign record, a link) stops the run. Exit status 1."""


@dataclass(frozen=True)
class Problem:
    path: str      # dotted field path, e.g. "objects[1].min_instances"
    message: str   # what is wrong
    fix: str       # what to do about it

    def __str__(self) -> str:
        return f"{self.path}: {self.message} (fix: {self.fix})"


class ConfigError(DataPipeError):
    """One or more configuration problems, all reported at once."""

    def __init__(self, problems: list[Problem] | Problem):
        if isinstance(problems, Problem):
            problems = [problems]
        self.problems = list(problems)
        lines = [f"{len(self.problems)} problem(s) in the configuration:"]
        lines += [f"  - {p}" for p in self.problems]
        super().__init__("\n".join(lines))

    def paths(self) -> list[str]:
        return [p.path for p in self.problems]


class ArgumentValueError(DataPipeError, ValueError):
    """A function argument has a wrong value or shape (also a ValueError for plain numpy code)."""


class ArgumentTypeError(DataPipeError, TypeError):
    """A function argument has a wrong type (also a TypeError)."""


def bad_value(arg: str, problem: str, fix: str) -> ArgumentValueError:
    return ArgumentValueError(f"{arg}: {problem} (fix: {fix})")


def bad_type(arg: str, problem: str, fix: str) -> ArgumentTypeError:
    return ArgumentTypeError(f"{arg}: {problem} (fix: {fix})")
