"""Checks of a preset and of a run's results. No bpy at import."""
