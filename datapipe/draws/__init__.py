"""Per-scene draws: seeds and the scene plan, camera poses, lighting, bin shape, fill. No bpy."""
