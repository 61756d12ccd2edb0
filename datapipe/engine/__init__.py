"""The run engine: the run loop, its world protocol, progress, Ray shards, Blender's log. No bpy at import."""
