"""Files, no bpy: the native output layout (names, "scene complete", atomic writes, readers) and the
writers (native scene.json, the original's output_dict.pickle, BOP) behind one small interface.

    layout   every file and folder name of a run, scene_complete, iter_scenes, config_identity
    files    atomic writes (text, bytes, JSON, images) and JSON readers
    native   scene.json
    legacy   output_dict.pickle (the original DataPipe's layout)
    models   PLY meshes (mm) and models_info.json: OUT/models and the BOP models
    bop      BOP export: depth encoding, silhouettes, statistics, BopWriter, export_bop
    writers  the writer interface built from cfg.output: start / has_scene / add_scene / finish

Importing this package imports nothing heavy; import the module you need.
"""
