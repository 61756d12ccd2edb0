"""The independent scene check (no bpy) against analytic geometry: boxes whose overlap, gaps and
floor depth are known exactly."""
import numpy as np
import pytest

from datapipe.checks.physics_check import Part, check_scene, point_triangle_distance, winding_number


def box(half):
    hx, hy, hz = half
    v = np.array([(x, y, z) for x in (-hx, hx) for y in (-hy, hy) for z in (-hz, hz)], dtype=float)
    quads = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for a, b, c, d in quads for t in ((a, b, c), (a, c, d))]
    return v, np.array(tris)


def pose(t, angle=0.0):
    T = np.eye(4)
    c, s = np.cos(angle), np.sin(angle)
    T[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
    T[:3, 3] = t
    return T


def test_winding_number_and_distance_of_a_box():
    v, f = box((0.01, 0.02, 0.03))
    P = np.array([[0, 0, 0], [0.009, 0.0, 0.0], [0.011, 0, 0], [0.05, 0.05, 0.05]])
    w = winding_number(P, v[f])
    assert np.allclose(w, [1, 1, 0, 0], atol=1e-9)
    d = point_triangle_distance(P, v[f])
    assert d == pytest.approx([0.01, 0.001, 0.001, np.linalg.norm([0.04, 0.03, 0.02])], abs=1e-12)


@pytest.mark.parametrize("overlap", [0.0003, 0.002])
def test_overlapping_boxes_give_the_overlap_depth(overlap):
    v, f = box((0.01, 0.01, 0.005))
    a = Part("a", v, f, pose([0, 0, 0.005]))
    b = Part("b", v, f, pose([0.02 - overlap, 0.003, 0.005], angle=0.0))
    res = check_scene([a, b], floor_z=0.0)
    assert res.max_depth == pytest.approx(overlap, abs=1e-9)
    assert (len(res.pairs) == 1) == (overlap > 0.0005)
    assert not res.floating and not res.below_floor


def test_rotated_box_corner_into_another():
    v, f = box((0.01, 0.01, 0.005))
    a = Part("a", v, f, pose([0, 0, 0.005]))
    d = 0.01 * np.sqrt(2)                      # half diagonal of the 45-degree box
    b = Part("b", v, f, pose([0.01 + d - 0.001, 0, 0.005], angle=np.pi / 4))   # its corner 1 mm in
    res = check_scene([a, b], floor_z=0.0)
    assert res.max_depth == pytest.approx(0.001, abs=1e-6)


def test_floating_and_below_floor():
    v, f = box((0.01, 0.01, 0.005))
    parts = [Part("rest", v, f, pose([0, 0, 0.005])),
             Part("float", v, f, pose([0.1, 0, 0.005 + 0.003])),      # 3 mm above the floor
             Part("sunk", v, f, pose([-0.1, 0, 0.005 - 0.001])),      # 1 mm into the floor
             Part("stacked", v, f, pose([0.0, 0, 0.0151]))]            # 0.1 mm above "rest"
    res = check_scene(parts, floor_z=0.0)
    assert [n for n, _ in res.floating] == ["float"]
    assert res.floating[0][1] == pytest.approx(0.003, abs=1e-9)
    assert [n for n, _ in res.below_floor] == ["sunk"]
    assert res.below_floor[0][1] == pytest.approx(0.001, abs=1e-9)


def test_leaning_on_a_wall_is_not_floating():
    v, f = box((0.01, 0.01, 0.005))
    p = Part("p", v, f, pose([0.09, 0, 0.02]))          # 15 mm up, touching the wall at x = 0.1
    res = check_scene([p], floor_z=0.0, walls=(np.zeros(3), np.array([0.1, 0.1, 0.1])))
    assert not res.floating
    res = check_scene([p], floor_z=0.0)
    assert res.floating and res.floating[0][1] == pytest.approx(0.015, abs=1e-9)


def test_part_fit_warns_for_a_part_larger_than_the_drop_zone(tmp_path):
    from datapipe.config import ObjectEntry, default_config
    from datapipe.checks.part_fit import mesh_extent, part_fit_warnings
    v, f = box((0.02, 0.01, 0.005))
    p = tmp_path / "box.obj"
    p.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v) + "".join(f"f {a+1} {b+1} {c+1}\n" for a, b, c in f))
    stl = tmp_path / "box.stl"                       # binary STL of the same box
    import struct
    stl.write_bytes(b"\0" * 80 + struct.pack("<I", len(f)) + b"".join(
        struct.pack("<12fH", 0, 0, 0, *v[a], *v[b], *v[c], 0) for a, b, c in f))
    assert mesh_extent(p) == pytest.approx([0.04, 0.02, 0.01])
    assert mesh_extent(stl) == pytest.approx([0.04, 0.02, 0.01])
    cfg = default_config()                          # zone 0.3 x 0.2 x 0.2 m
    assert part_fit_warnings(cfg) == []             # the demo parts fit
    cfg.objects = [ObjectEntry(filepath=str(p), scale=1.0), ObjectEntry(filepath=str(stl), scale=5.0)]
    w = part_fit_warnings(cfg)                      # 0.2 x 0.1 x 0.05 m: sphere 0.229 m > 0.2 m
    assert len(w) == 1 and w[0].startswith("objects[1]:") and "drop_zone_scale" in w[0]


def test_part_fit_reads_ply_with_the_model_reader_in_every_encoding(tmp_path):
    """part_fit's extent of a PLY comes from io.models.read_ply (one PLY reader): ascii, binary
    little endian (write_ply) and a hand-written binary big endian file give the box's size."""
    from datapipe.io.models import read_ply, write_ply
    from datapipe.checks.part_fit import mesh_extent
    v, f = box((0.02, 0.01, 0.005))
    for binary in (True, False):
        p = tmp_path / f"box_{binary}.ply"
        write_ply(p, v, f, binary=binary)
        assert mesh_extent(p) == pytest.approx([0.04, 0.02, 0.01], abs=1e-7)    # float32 in the file
    big = tmp_path / "box_be.ply"
    head = (f"ply\nformat binary_big_endian 1.0\nelement vertex {len(v)}\nproperty double x\n"
            f"property double y\nproperty double z\nelement face {len(f)}\n"
            "property list uchar int vertex_indices\nend_header\n")
    rec = np.zeros(len(f), dtype=[("n", "u1"), ("i", ">i4", (3,))])
    rec["n"], rec["i"] = 3, f
    big.write_bytes(head.encode() + np.asarray(v, dtype=">f8").tobytes() + rec.tobytes())
    V, F = read_ply(big)
    np.testing.assert_array_equal(V, v)
    np.testing.assert_array_equal(F, f)
    assert mesh_extent(big) == pytest.approx([0.04, 0.02, 0.01])
    (tmp_path / "bad.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nend_header\n")
    assert mesh_extent(tmp_path / "bad.ply") is None        # unread: the check is skipped, no traceback


def test_physics_line_and_totals_say_what_went_wrong():
    from datapipe.checks.physics_check import add_to_totals, physics_line, totals_line
    sim = {"parts": 9, "frames": 200, "settled": False, "substeps": 13, "attempts": 2,
           "removed": [{"name": "a", "reason": "left the bin"}, {"name": "b", "reason": "fell through the floor"}],
           "unsettled": [{"name": "c", "speed": 0.3}], "interpenetrating_pairs": [{"a": "d", "b": "e", "depth_mm": 1.2}],
           "max_interpenetration_mm": 1.2, "below_floor": [], "floating": [{"name": "f", "gap_mm": 3.0}]}
    assert physics_line(sim) == ("9 parts, 2 removed (fell through the floor, left the bin), 1 unsettled, "
                                 "1 interpenetrating (max 1.2 mm), 1 floating, 200 frames x 13 substeps, drop 2")
    assert physics_line({"frames": 75, "settled": True, "removed": []}) == "75 frames"    # an older record
    t = add_to_totals(add_to_totals({}, sim), {"parts": 3, "frames": 40, "settled": True, "removed": []})
    assert t["parts"] == 12 and t["scenes"] == 2 and t["removed"] == 2 and t["unsettled_scenes"] == 1
    assert t["redrawn_scenes"] == 1 and t["max_interpenetration_mm"] == 1.2
    assert totals_line(t).startswith("physics: 12 parts in 2 scenes, 2 removed, 1 unsettled, 1 interpenetrating")
