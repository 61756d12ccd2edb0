"""Checks of a run's inputs. `run_checks` is the one gate every entry calls before a run
(config rules -> mesh preflight -> part fit -> device -> memory -> output folder; see gate.py)."""
from .gate import CheckReport, run_checks

__all__ = ["CheckReport", "run_checks"]
