"""Errors raised by :mod:`datapipe.sl` for bad arguments.

They are both :class:`datapipe.errors.DataPipeError` (so the CLI and the UI report them as user
mistakes, without a traceback) and the builtin ``ValueError`` / ``TypeError`` (so plain numpy code
and ``pytest.raises(ValueError)`` catch them). Messages name the argument and the fix.
"""
from __future__ import annotations

from ..errors import ArgumentTypeError, ArgumentValueError


class SLValueError(ArgumentValueError):
    """An argument of a structured-light function has a wrong value or shape."""


class SLTypeError(ArgumentTypeError):
    """An argument of a structured-light function has a wrong type."""


def bad_value(arg: str, problem: str, fix: str) -> SLValueError:
    return SLValueError(f"{arg}: {problem} (fix: {fix})")


def bad_type(arg: str, problem: str, fix: str) -> SLTypeError:
    return SLTypeError(f"{arg}: {problem} (fix: {fix})")
