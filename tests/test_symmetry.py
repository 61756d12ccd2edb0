"""Symmetry detection on the shipped parts, whose symmetries are known by construction
(scripts/make_assets.py): the hex nut (6-fold about z, and the six half turns that flip it), the
peg (a 24-sided prism: a body of revolution within 0.1 mm, and its flip), the L-bracket (none).
Each found transform is checked independently: it maps the mesh's vertex set onto itself."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from datapipe.errors import DataPipeError
from datapipe.io.symmetry import TOLERANCE, check_symmetries, detect_symmetries

ASSETS = Path(__file__).resolve().parents[1] / "datapipe" / "assets"


def load_obj_mm(name):
    V, F = [], []
    for line in (ASSETS / f"{name}.obj").read_text().splitlines():
        t = line.split()
        if t and t[0] == "v":
            V.append([float(x) * 1000.0 for x in t[1:4]])
        elif t and t[0] == "f":
            idx = [int(x.split("/")[0]) - 1 for x in t[1:]]
            F += [[idx[0], idx[k], idx[k + 1]] for k in range(1, len(idx) - 1)]
    return np.array(V), np.array(F)


def maps_vertices_onto_themselves(V, T, atol):
    W = V @ T[:3, :3].T + T[:3, 3]
    d = np.linalg.norm(W[:, None, :] - V[None, :, :], axis=2).min(axis=1)
    return d.max() <= atol


def test_nut_six_fold_and_flip():
    V, F = load_obj_mm("nut")
    s = detect_symmetries(V, F)
    assert s["symmetries_continuous"] == []
    Ts = [np.array(t).reshape(4, 4) for t in s["symmetries_discrete"]]
    assert len(Ts) == 11                                # the dihedral group D6 less the identity
    turns_z = [T for T in Ts if abs(T[2, 2] - 1) < 1e-6]
    flips = [T for T in Ts if abs(T[2, 2] + 1) < 1e-6]
    assert len(turns_z) == 5 and len(flips) == 6
    angles = sorted(round(np.degrees(np.arctan2(T[1, 0], T[0, 0])) % 360) for T in turns_z)
    assert angles == [60, 120, 180, 240, 300]
    for T in Ts:
        np.testing.assert_allclose(T[3], [0, 0, 0, 1])
        np.testing.assert_allclose(T[:3, :3] @ T[:3, :3].T, np.eye(3), atol=1e-6)
        assert maps_vertices_onto_themselves(V, T, atol=0.01)     # the file rounds to 1 um


def test_peg_continuous_with_flip():
    V, F = load_obj_mm("peg")
    s = detect_symmetries(V, F)
    (c,) = s["symmetries_continuous"]
    np.testing.assert_allclose(np.abs(c["axis"]), [0, 0, 1], atol=1e-6)
    np.testing.assert_allclose(c["offset"], [0, 0, 0], atol=1e-6)
    (flip,) = s["symmetries_discrete"]
    T = np.array(flip).reshape(4, 4)
    assert T[2, 2] == pytest.approx(-1)
    assert maps_vertices_onto_themselves(V, T, atol=12 * (1 - np.cos(np.pi / 24)) + 0.01)


def test_bracket_none():
    V, F = load_obj_mm("bracket")
    assert detect_symmetries(V, F) == {"symmetries_discrete": [], "symmetries_continuous": []}


def test_tolerance_is_what_it_says():
    """The nut with its hole moved off-centre by 3x the tolerance keeps only the flip that keeps the
    hole (the half turn about the axis along the shift); moved by 0.4x the tolerance (a half turn
    moves it by 0.8x) it keeps all 11."""
    V, F = load_obj_mm("nut")
    dia = 36.64
    for factor, n in ((3.0, 1), (0.4, 11)):
        V2 = V.copy()
        V2[12:, 0] += factor * TOLERANCE * dia          # the hole's 12 vertices
        s = detect_symmetries(V2, F)
        assert s["symmetries_continuous"] == []
        assert len(s["symmetries_discrete"]) == n, factor
        if n == 1:
            T = np.array(s["symmetries_discrete"][0]).reshape(4, 4)
            assert maps_vertices_onto_themselves(V2, T, atol=0.01)


def test_check_symmetries_names_the_field():
    ok = check_symmetries({"symmetries_discrete": [np.eye(4).reshape(-1).tolist()],
                           "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 0]}]}, "x")
    assert len(ok["symmetries_discrete"]) == 1
    with pytest.raises(DataPipeError, match=r"objects\[0\].symmetries.symmetries_discrete\[0\]: expected 16"):
        check_symmetries({"symmetries_discrete": [[1, 0, 0]]}, "objects[0].symmetries")
    with pytest.raises(DataPipeError, match="not a rigid transform"):
        check_symmetries({"symmetries_discrete": [(2 * np.eye(4)).reshape(-1).tolist()]}, "s")
    with pytest.raises(DataPipeError, match=r"symmetries_continuous\[0\]"):
        check_symmetries({"symmetries_continuous": [{"axis": [0, 0, 0], "offset": [0, 0, 0]}]}, "s")
    with pytest.raises(DataPipeError, match="unknown keys"):
        check_symmetries({"discrete": []}, "s")
