"""What Blender itself says about the objects DataPipe built: read-outs for the tests (the package
never reads these back, so they live here, not in datapipe/core)."""
import numpy as np

from datapipe.core.compat import IS_5
from datapipe.geometry import blender_camera_to_opencv


def file_output_input_names(fo) -> list[str]:
    """The inputs of a File Output node (5.x: file_output_items, 4.2: layer_slots)."""
    if IS_5:
        return [item.name for item in fo.file_output_items]
    return [slot.name for slot in fo.layer_slots]


def light_world_pose(proj, i: int = 0) -> np.ndarray:
    """Projector light i's world pose as Blender evaluates it, in the OpenCV projector frame.

    Evaluated in its own fringe view layer when that exists (the light is excluded from every other
    layer, where its matrix_world is not updated); else parent @ parent_inverse @ basis. The scale of
    the camera object (its parent) is removed."""
    ob = proj.lights[i]
    layers = proj.view_layers
    if i < len(layers):
        vl = layers[i]
        vl.update()
        M = ob.evaluated_get(vl.depsgraph).matrix_world
    else:
        M = proj.camera_obj.matrix_world @ ob.matrix_parent_inverse @ ob.matrix_basis
    M = np.array(M, dtype=np.float64)
    M[:3, :3] /= np.linalg.norm(M[:3, :3], axis=0, keepdims=True)
    return blender_camera_to_opencv(M)
