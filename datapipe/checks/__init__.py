"""Checks of a run's inputs and results. `run_checks` is the one gate every entry calls before a run
(config rules -> output folder -> mesh preflight -> part fit -> device -> memory; see gate.py); the
other modules are the checks it calls (part_fit, device_checks), the rules the config's own
validation uses (text_rules, pickle_depth) and the checks of a run's results (physics_check, quality).

`run_checks` and `CheckReport` are imported on first use: the config package imports text_rules and
pickle_depth from here, and the gate imports the config package."""

__all__ = ["CheckReport", "run_checks"]


def __getattr__(name):
    if name in __all__:
        from . import gate
        return getattr(gate, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
