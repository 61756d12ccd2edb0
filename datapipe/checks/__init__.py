"""Checks a run's gate calls and checks of a run's results. No bpy.

The gate itself, `run_checks`, is run by the run engine (datapipe/engine/gate.py): it drives the
Blender preflight (core/), so it sits above core/; the checks here sit below it and import neither:
- of a preset: part_fit (the parts against the bin and its drop zone), device_checks (a device's
  field of view and precision), origins (a mesh's origin far from its box's centre);
- of a run's results: physics_check (a frozen scene: interpenetration, under the floor, floating;
  core/simulation.py calls it), quality (each render's quality gates).
The rules of a config's own fields live with the Config (datapipe/config/, datapipe/text_rules.py).
"""
