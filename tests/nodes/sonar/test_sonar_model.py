"""Structure models: surface samples lie on the surfaces with outward normals; PLY/OBJ load the same mesh."""
from __future__ import annotations

import struct

import numpy as np
import pytest

from nodes.sonar.model import (load_mesh, sample_box, sample_cylinder, sample_mesh, sample_structures,
                               tripod_model, tripod_structures)

CUBE_V = [(0, 0, 0), (2, 0, 0), (2, 2, 0), (0, 2, 0), (0, 0, 2), (2, 0, 2), (2, 2, 2), (0, 2, 2)]
CUBE_F = [(0, 3, 2, 1), (4, 5, 6, 7), (0, 1, 5, 4), (1, 2, 6, 5), (2, 3, 7, 6), (3, 0, 4, 7)]


def test_cylinder_samples_on_surface_with_outward_normals() -> None:
    p, n = sample_cylinder([1, 2, 3], [4, 6, 3], 0.5, 0.05)
    axis = np.array([3.0, 4.0, 0.0]) / 5
    rel = p - [1, 2, 3]
    radial = rel - np.outer(rel @ axis, axis)
    np.testing.assert_allclose(np.linalg.norm(radial, axis=1), 0.5, atol=1e-9)
    np.testing.assert_allclose(np.einsum("ij,ij->i", radial / 0.5, n), 1.0, atol=1e-9)


def test_box_faces_and_yaw() -> None:
    p, n = sample_box([0, 0, 1], [2, 4, 2], np.radians(90), 0.1)
    assert np.all(n[:, 2] >= 0)                                     # no bottom face by default
    np.testing.assert_allclose(np.abs(p[:, 0]).max(), 2.0, atol=1e-9)   # yawed 90 deg: long side along x
    centre = np.array([0, 0, 1.0])
    assert np.all(np.einsum("ij,ij->i", p - centre, n) > 0)


def _write_ply_ascii(path) -> None:
    lines = ["ply", "format ascii 1.0", "element vertex 8", "property float x", "property float y",
             "property float z", "element face 6", "property list uchar int vertex_indices", "end_header"]
    lines += [" ".join(map(str, v)) for v in CUBE_V] + [f"4 {' '.join(map(str, f))}" for f in CUBE_F]
    path.write_text("\n".join(lines) + "\n")


def _write_ply_binary(path) -> None:
    head = ("ply\nformat binary_little_endian 1.0\nelement vertex 8\nproperty float x\nproperty float y\n"
            "property float z\nelement face 6\nproperty list uchar int vertex_indices\nend_header\n").encode()
    body = b"".join(struct.pack("<3f", *v) for v in CUBE_V)
    body += b"".join(struct.pack("<B4i", 4, *f) for f in CUBE_F)
    path.write_bytes(head + body)


def _write_obj(path) -> None:
    path.write_text("".join(f"v {x} {y} {z}\n" for x, y, z in CUBE_V)
                    + "".join("f " + " ".join(str(i + 1) for i in f) + "\n" for f in CUBE_F))


@pytest.mark.parametrize("writer,name", [(_write_ply_ascii, "c.ply"), (_write_ply_binary, "c.ply"), (_write_obj, "c.obj")])
def test_mesh_files_load_to_the_same_cube(tmp_path, writer, name) -> None:
    path = tmp_path / name
    writer(path)
    v, f = load_mesh(path)
    assert v.shape == (8, 3) and f.shape == (12, 3)
    p, n = sample_mesh(v, f, 0.1)
    assert len(p) >= 2400 and np.all(p >= -1e-9) and np.all(p <= 2 + 1e-9)
    assert np.all(np.einsum("ij,ij->i", p - 1.0, n) > 0)             # outward normals


def test_bad_mesh_inputs_raise(tmp_path) -> None:
    (tmp_path / "x.stl").write_text("solid")
    with pytest.raises(ValueError, match=".obj or .ply"):
        load_mesh(tmp_path / "x.stl")
    (tmp_path / "bad.ply").write_bytes(b"not a ply")
    with pytest.raises(ValueError, match="not a PLY"):
        load_mesh(tmp_path / "bad.ply")
    with pytest.raises(ValueError, match="out of range"):
        sample_mesh(np.zeros((3, 3)), np.array([[0, 1, 5]]))
    with pytest.raises(ValueError, match="unknown structure"):
        sample_structures([{"type": "sphere"}])


def test_tripod_without_pylons_is_three_fold_symmetric() -> None:
    from scipy.spatial import cKDTree

    p, _ = tripod_model(pylons=False, spacing_m=0.2)
    a = np.radians(120)
    rot = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
    d, _ = cKDTree(p).query(p @ rot.T)
    assert np.percentile(d, 99) < 0.15
    with_pylons, _ = tripod_model(pylons=True, spacing_m=0.2)
    d2, _ = cKDTree(with_pylons).query(with_pylons @ rot.T)
    assert np.percentile(d2, 99) > 1.0
    assert len(tripod_structures()) == len(tripod_structures(pylons=False)) + 2


def test_tripod_model_has_the_exposed_column_top_and_no_buried_samples() -> None:
    pts, nrm = tripod_model(spacing_m=0.1)
    top = (np.abs(pts[:, 2] + 2.0) < 1e-9) & (np.hypot(pts[:, 0], pts[:, 1]) < 0.55)
    assert top.sum() > 50 and np.allclose(nrm[top], [0, 0, 1])         # the column's cap, facing up
    assert pts[:, 2].min() > -6.0 + 1e-3                                # nothing on or under the seabed
    inside_mat = (np.abs(pts[:, 0]) < 0.85) & (np.abs(pts[:, 1] - 6.0) < 0.85) & (pts[:, 2] < -5.61)
    assert not inside_mat.any()                                         # the north leg's foot is inside its mat
    apex = np.linalg.norm(pts - [0.0, 0.0, -2.5], axis=1) < 0.3
    assert not apex.any()                                               # the legs' upper ends are inside the column


def test_capped_cylinder_caps_face_outwards() -> None:
    p, n = sample_cylinder([0, 0, 0], [0, 0, 2], 0.5, 0.1, caps=True)
    cap = np.abs(n[:, 2]) > 0.5
    assert cap.sum() > 40
    np.testing.assert_allclose(n[cap, 2], np.sign(p[cap, 2] - 1.0))
    assert np.all(np.hypot(p[cap, 0], p[cap, 1]) < 0.5)
