"""Every sidebar operator through bpy.ops.datapipe.*: lists, previews (no stray data), drop zone, errors."""
import bpy
import pytest
from mathutils import Quaternion

from datapipe.core import scene as core_scene
import datapipe.ui as ui
from datapipe.ui import preview
from datapipe.ui.convert import props_to_config


@pytest.fixture(autouse=True)
def d(ui_props):
    return ui_props


def counts():
    data = bpy.data
    return {k: len(getattr(data, k)) for k in ("objects", "meshes", "cameras", "lights", "materials", "images",
                                                 "collections")}


# ------------------------------------------------------------------------------------------------
# objects

def test_object_add_remove_reorder(d, assets_dir):
    bpy.ops.datapipe.object_add(filepath=str(assets_dir / "peg.obj"))
    bpy.ops.datapipe.object_add(filepath=str(assets_dir / "nut.obj"))
    bpy.ops.datapipe.object_add()
    assert [o.filepath.rsplit("/", 1)[-1] for o in d.objects] == ["peg.obj", "nut.obj", ""]
    assert d.objects_index == 2
    assert d.objects[2].mass == pytest.approx(0.05) and d.objects[2].collision_shape == "AUTO"
    d.objects_index = 1
    bpy.ops.datapipe.object_move(direction="UP")
    assert d.objects_index == 0
    assert d.objects[0].filepath.endswith("nut.obj")
    bpy.ops.datapipe.object_move(direction="UP")             # already first: stays
    assert d.objects_index == 0
    bpy.ops.datapipe.object_move(direction="DOWN")
    assert d.objects[1].filepath.endswith("nut.obj")
    bpy.ops.datapipe.object_remove()
    assert len(d.objects) == 2 and d.objects_index == 1
    bpy.ops.datapipe.object_remove()
    bpy.ops.datapipe.object_remove()
    assert len(d.objects) == 0
    with pytest.raises(RuntimeError, match="objects: nothing selected"):
        bpy.ops.datapipe.object_remove()


def test_object_preview_toggle_leaves_no_data(d, assets_dir):
    bpy.ops.datapipe.object_add(filepath=str(assets_dir / "bracket.obj"))
    d.objects[0].scale = 2.0
    before = counts()
    bpy.ops.datapipe.object_preview()
    objs = preview.tagged("object")
    assert objs and all(o.users_collection[0].name == preview.COLLECTION for o in objs)
    assert objs[0].scale[:] == pytest.approx((2.0, 2.0, 2.0))
    assert objs[0].location[:] == pytest.approx(tuple(d.scene.drop_zone_loc))
    d.objects[0].scale = 0.5                                  # the preview follows the scale
    assert objs[0].scale[:] == pytest.approx((0.5, 0.5, 0.5))
    assert counts() != before
    bpy.ops.datapipe.object_preview()
    assert counts() == before
    assert bpy.data.collections.get(preview.COLLECTION) is None


def test_object_preview_errors_name_the_field(d, tmp_path):
    with pytest.raises(RuntimeError, match="no object entry selected"):
        bpy.ops.datapipe.object_preview()
    bpy.ops.datapipe.object_add()
    with pytest.raises(RuntimeError, match=r"objects\[0\]\.filepath: empty"):
        bpy.ops.datapipe.object_preview()
    d.objects[0].filepath = str(tmp_path / "missing.obj")
    with pytest.raises(RuntimeError, match=r"objects\[0\]\.filepath: file not found"):
        bpy.ops.datapipe.object_preview()
    bad = tmp_path / "broken.obj"
    bad.write_text("this is not an obj file\n")
    d.objects[0].filepath = str(bad)
    before = counts()
    with pytest.raises(RuntimeError, match=r"objects\[0\]\.filepath: .* holds no mesh"):
        bpy.ops.datapipe.object_preview()
    assert counts() == before


# ------------------------------------------------------------------------------------------------
# camera

def test_camera_preview_pose_add_jump_remove(d):
    before = counts()
    with pytest.raises(RuntimeError, match="camera.poses: the camera preview is off"):
        bpy.ops.datapipe.pose_add()
    bpy.ops.datapipe.camera_preview()
    cam = preview.camera_object()
    assert cam is not None and cam.type == "CAMERA"
    assert cam.data.lens == pytest.approx(d.camera.focal_length)
    d.camera.focal_length = 25.0                              # live intrinsics
    assert cam.data.lens == pytest.approx(25.0)
    assert (bpy.context.scene.render.resolution_x, bpy.context.scene.render.resolution_y) == tuple(d.camera.resolution)

    cam.location = (0.1, -0.2, 0.9)
    cam.rotation_quaternion = Quaternion((0.0, 1.0, 0.0), 0.3)
    bpy.ops.datapipe.pose_add()
    cam.location = (0.0, 0.0, 1.5)
    cam.rotation_quaternion = (1, 0, 0, 0)
    bpy.ops.datapipe.pose_add()
    assert len(d.camera.poses) == 2 and d.camera.poses_index == 1
    p0 = props_to_config(d).camera.poses[0]
    assert p0.location == pytest.approx([0.1, -0.2, 0.9], abs=1e-6)
    assert p0.rotation == pytest.approx(list(Quaternion((0.0, 1.0, 0.0), 0.3)), abs=1e-6)

    bpy.ops.datapipe.pose_jump(index=0)                       # moves the preview camera
    assert d.camera.poses_index == 0
    assert cam.location[:] == pytest.approx((0.1, -0.2, 0.9), abs=1e-6)
    bpy.ops.datapipe.pose_move(direction="DOWN")
    assert d.camera.poses_index == 1
    assert props_to_config(d).camera.poses[1].location == pytest.approx([0.1, -0.2, 0.9], abs=1e-6)
    bpy.ops.datapipe.pose_remove()
    assert len(d.camera.poses) == 1
    assert props_to_config(d).camera.poses[0].location == pytest.approx([0.0, 0.0, 1.5])

    bpy.ops.datapipe.camera_preview()                         # off: nothing left behind
    assert counts() == before
    with pytest.raises(RuntimeError, match=r"camera.poses: nothing selected"):
        bpy.ops.datapipe.pose_jump(index=5)


def test_jump_turns_camera_preview_on(d):
    pose = d.camera.poses.add()
    pose.location = (0.0, 0.3, 1.2)
    before = counts()
    bpy.ops.datapipe.pose_jump()
    assert preview.camera_object().location[:] == pytest.approx((0.0, 0.3, 1.2))
    bpy.ops.datapipe.camera_preview()
    assert counts() == before


def test_projector_preview(d):
    before = counts()
    with pytest.raises(RuntimeError, match="turn on the camera preview"):
        bpy.ops.datapipe.projector_preview()
    bpy.ops.datapipe.camera_preview()
    bpy.ops.datapipe.projector_preview()
    proj = preview.tagged("projector")[0]
    cam = preview.camera_object()
    assert proj.type == "LIGHT" and proj.data.type == "SPOT" and proj.parent == cam
    assert proj.location[:] == pytest.approx(tuple(d.projector.location))
    d.projector.location = (-0.2, 0.01, 0.0)                   # follows edits
    assert proj.location[:] == pytest.approx((-0.2, 0.01, 0.0))
    d.projector.rotation_euler = (0.0, -0.3, 0.0)
    assert proj.rotation_euler[1] == pytest.approx(-0.3, abs=1e-6)
    bpy.ops.datapipe.projector_preview()                      # off
    assert not preview.is_on("projector") and preview.is_on("camera")
    bpy.ops.datapipe.projector_preview()
    bpy.ops.datapipe.camera_preview()                         # camera off takes the projector along
    assert counts() == before


# ------------------------------------------------------------------------------------------------
# drop zone

def test_drop_zone_place_and_read_back(d):
    assert preview.DROP_ZONE_NAME == core_scene.DROP_ZONE_NAME
    d.scene.drop_zone_loc = (0.1, 0.2, 0.3)
    d.scene.drop_zone_scale = (0.2, 0.1, 0.05)
    bpy.ops.datapipe.drop_zone_place()
    obj = bpy.data.objects["drop_zone"]
    assert obj.display_type == "WIRE" and obj.hide_render
    assert obj.location[:] == pytest.approx((0.1, 0.2, 0.3))
    assert obj.dimensions[:] == pytest.approx((0.4, 0.2, 0.1))
    n = counts()
    bpy.ops.datapipe.drop_zone_place()                        # again: moves, never duplicates
    assert counts() == n
    obj.location = (0.0, 0.0, 0.5)
    obj.scale = (0.3, 0.3, 0.3)
    bpy.ops.datapipe.drop_zone_read()
    assert tuple(d.scene.drop_zone_loc) == pytest.approx((0.0, 0.0, 0.5))
    assert tuple(d.scene.drop_zone_scale) == pytest.approx((0.3, 0.3, 0.3))


def test_drop_zone_read_without_object(d):
    with pytest.raises(RuntimeError, match="no object named 'drop_zone'"):
        bpy.ops.datapipe.drop_zone_read()


# ------------------------------------------------------------------------------------------------
# check / run errors (no rendering)

def test_run_with_missing_file_names_the_field(d, tmp_path):
    bpy.ops.datapipe.initialize(preset="builtin:default")
    d.objects[1].filepath = str(tmp_path / "gone.obj")
    d.output.path = str(tmp_path / "out")
    with pytest.raises(RuntimeError, match=r"objects\[1\]\.filepath: file not found"):
        bpy.ops.datapipe.run(blocking=True)
    with pytest.raises(RuntimeError, match=r"objects\[1\]\.filepath"):
        bpy.ops.datapipe.check()
    assert not (tmp_path / "out").exists()                    # nothing written


def test_run_reports_every_problem(d, tmp_path):
    d.output.path = str(tmp_path / "out")
    with pytest.raises(RuntimeError) as e:
        bpy.ops.datapipe.run(blocking=True)
    msg = str(e.value)
    assert "objects: no objects to drop" in msg and "camera.poses: no camera poses" in msg
    assert "Traceback" not in msg


def test_run_refuses_non_empty_output(d, tmp_path):
    bpy.ops.datapipe.initialize(preset="builtin:default")
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    d.output.path = str(out)
    with pytest.raises(RuntimeError, match="not empty"):
        bpy.ops.datapipe.run(blocking=True)
    assert [p.name for p in out.iterdir()] == ["keep.txt"]


def test_check_ok(d, tmp_path):
    bpy.ops.datapipe.initialize(preset="builtin:default")
    d.output.path = str(tmp_path / "out")
    assert bpy.ops.datapipe.check() == {"FINISHED"}


def test_cancel_without_run_is_unavailable(d):
    assert not bpy.ops.datapipe.cancel.poll()
