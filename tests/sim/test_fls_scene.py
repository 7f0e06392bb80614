"""FLS scene geometry: ray casting against analytic ground truth, shadows, poses, surface samples."""
from __future__ import annotations

import numpy as np
import pytest

from sim.fls_scene import (Box, Cylinder, HeightField, Mesh, Plane, cast_rays, load_scene, sample_structures,
                           sonar_frame)


def _unit(v) -> np.ndarray:
    v = np.atleast_2d(np.asarray(v, float))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _scene(structures=(), floor=None) -> dict:
    return {"name": "t", "seafloor": floor or {"type": "plane", "z_m": -6.0}, "structures": list(structures)}


def test_plane_range_is_altitude_over_sine_of_depression():
    scene = load_scene(_scene())
    dep = np.radians([5.0, 15.0, 25.0, 90.0])
    dirs = np.stack([np.cos(dep), 0 * dep, -np.sin(dep)], axis=1)
    t, n, lab = cast_rays(scene, np.array([0, 0, -1.0]), dirs)
    np.testing.assert_allclose(t, 5.0 / np.sin(dep))
    assert np.all(lab == 0) and np.allclose(n, [0, 0, 1])
    up, _, lab_up = cast_rays(scene, np.array([0, 0, -1.0]), _unit([1, 0, 0.1]))
    assert np.isinf(up[0]) and lab_up[0] == -1


def test_cylinder_side_and_cap_hits_with_normals():
    cyl = Cylinder(np.array([5.0, 0, -3]), np.array([5.0, 0, 3]), 1.0)
    t, n = cyl.intersect(np.zeros(3), _unit([[1, 0, 0], [1, 0.1, 0], [0, 1, 0]]))
    assert t[0] == pytest.approx(4.0) and np.allclose(n[0], [-1, 0, 0])
    y = 0.1 * t[1] / np.hypot(1, 0.1)                     # hit point on the circle (x-5)^2 + y^2 = 1
    assert (t[1] / np.hypot(1, 0.1) - 5) ** 2 + y ** 2 == pytest.approx(1.0)
    assert np.isinf(t[2])
    t_cap, n_cap = cyl.intersect(np.array([5.0, 0.2, 10.0]), _unit([0, 0, -1]))
    assert t_cap[0] == pytest.approx(7.0) and np.allclose(n_cap[0], [0, 0, 1])


def test_box_face_hit_and_rotation():
    box = Box(np.array([10.0, 0, 0]), np.array([2.0, 4, 2]), np.eye(3))
    t, n = box.intersect(np.zeros(3), _unit([[1, 0, 0], [1, 0.5, 0]]))
    assert t[0] == pytest.approx(9.0) and np.allclose(n[0], [-1, 0, 0])
    assert np.isinf(t[1])
    c, s = np.cos(np.pi / 4), np.sin(np.pi / 4)
    turned = Box(np.array([10.0, 0, 0]), np.array([2.0, 2, 2]), np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]))
    t2, _ = turned.intersect(np.zeros(3), _unit([1, 0, 0]))
    assert t2[0] == pytest.approx(10 - np.sqrt(2))             # the corner points at the sonar


def test_mesh_triangle_hit_and_miss():
    mesh = Mesh(np.array([[5.0, -1, -1], [5.0, 1, -1], [5.0, 0, 1]]), np.array([[0, 1, 2]]))
    t, n = mesh.intersect(np.zeros(3), _unit([[1, 0, 0], [1, 0.5, 0]]))
    assert t[0] == pytest.approx(5.0) and np.allclose(n[0], [-1, 0, 0]) and np.isinf(t[1])


def test_flat_heightfield_matches_the_plane_and_a_bump_is_found():
    flat = HeightField(np.full((30, 30), -6.0), (-15.0, -15.0), 1.0)
    dirs = _unit([[1, 0, -0.3], [0.5, 0.5, -1], [0, 1, -0.1]])
    t_hf, _ = flat.intersect(np.array([0, 0, -1.0]), dirs)
    t_pl, _ = Plane(-6.0).intersect(np.array([0, 0, -1.0]), dirs)
    np.testing.assert_allclose(t_hf, t_pl, rtol=1e-3)
    bump = np.full((30, 30), -6.0)
    bump[15, 19] = -4.0                                         # a 2 m peak at (4, 0), bilinear slopes
    ray = _unit([1, 0, -0.9])
    t_b, n_b = HeightField(bump, (-15.0, -15.0), 1.0).intersect(np.array([0, 0, -1.0]), ray)
    t_floor, _ = Plane(-6.0).intersect(np.array([0, 0, -1.0]), ray)
    assert t_b[0] < t_floor[0] - 1.5 and n_b[0, 0] < 0           # hit the mound's sonar-facing slope
    hit_z = -1.0 + t_b[0] * ray[0, 2]
    assert -6.0 < hit_z < -4.0


def test_first_hit_only_makes_shadows():
    scene = load_scene(_scene([{"type": "cylinder", "from_m": [8, 0, -6], "to_m": [8, 0, 0], "radius_m": 0.5}]))
    origin = np.array([0, 0, -1.0])
    dirs = _unit([[np.cos(a), 0, -np.sin(a)] for a in np.radians([10, 45])])
    t, _, lab = cast_rays(scene, origin, dirs)
    assert lab[0] == 1 and t[0] < 8.0                           # blocked by the pile: no seafloor behind it
    assert lab[1] == 0 and t[1] == pytest.approx(5 / np.sin(np.radians(45)))


def test_sonar_frame_is_frd_tilted_down():
    pose = sonar_frame(np.array([1.0, 2.0, -1.0]), np.pi / 2, np.radians(15))   # heading north
    rot = pose[:3, :3]
    np.testing.assert_allclose(rot @ rot.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    boresight, starboard = rot[:, 0], rot[:, 1]
    assert boresight[1] > 0.96 and boresight[2] == pytest.approx(-np.sin(np.radians(15)))
    np.testing.assert_allclose(starboard, [1, 0, 0], atol=1e-12)               # east is to starboard
    assert rot[2, 2] < 0                                                        # head z points down-ish


def test_boat_runs_back_and_forth():
    scene = load_scene("tripod")
    p = scene.platform
    leg_s = np.linalg.norm(p.end - p.start) / p.speed_mps
    out, back = scene.sonar_pose(0.25 * leg_s), scene.sonar_pose(1.75 * leg_s)
    np.testing.assert_allclose(out[:3, 3], back[:3, 3], atol=1e-9)             # same place, opposite ways
    assert out[1, 0] > 0.9 and back[1, 0] < -0.9 and out[2, 3] == -p.depth_m   # north, then south
    np.testing.assert_allclose(scene.sonar_pose(2 * leg_s), scene.sonar_pose(0.0), atol=1e-9)


def test_tripod_scene_has_two_pylons_through_the_surface():
    scene = load_scene("tripod")
    tops = [max(s.p0[2], s.p1[2]) for s in scene.structures if isinstance(s, Cylinder)]
    assert sum(top > 0 for top in tops) == 2
    assert scene.seafloor.z_m < -5 and np.degrees(scene.sonar.tilt_rad) == pytest.approx(15)
    assert scene.sonar.modes["low"]["horizontal_aperture_deg"] == 130
    assert scene.sonar.modes["high"]["vertical_aperture_deg"] == 12


def test_structure_samples_lie_on_the_surfaces():
    scene = load_scene("tripod")
    pts, normals = sample_structures(scene, spacing_m=0.2)
    assert len(pts) > 1000 and np.allclose(np.linalg.norm(normals, axis=1), 1.0)
    # cast from just outside each sampled point, back along its normal: the surface is right there
    rng = np.random.default_rng(0)
    pick = rng.choice(len(pts), 200, replace=False)
    for i in pick:
        t, _, lab = cast_rays(scene, pts[i] + 0.01 * normals[i], -normals[i][None])
        assert t[0] == pytest.approx(0.01, abs=0.005) and lab[0] >= 1
    assert len(sample_structures(load_scene("flat"))[0]) == 0


def test_bad_scenes_raise_clear_errors():
    with pytest.raises(ValueError, match="no FLS scene"):
        load_scene("atlantis")
    with pytest.raises(ValueError, match="cylinder, box or mesh"):
        load_scene(_scene([{"type": "sphere"}]))
    with pytest.raises(ValueError, match="sonar"):
        load_scene({**_scene(), "sonar": {"beams_per_fish": 3}})


def _cube_mesh(size=2.0):
    v = np.array([[x, y, z] for x in (0, size) for y in (0, size) for z in (0, size)], float)
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return v, faces


def test_mesh_inside_by_winding_number_matches_a_box_and_survives_a_missing_face():
    v, f = _cube_mesh()
    # orient outward whatever the table above says: flip if the signed volume is negative
    if np.einsum("ij,ij->i", v[f[:, 0]], np.cross(v[f[:, 1]], v[f[:, 2]])).sum() < 0:
        f = f[:, ::-1]
    box = Box(center=np.array([1.0, 1.0, 1.0]), size=np.array([2.0, 2.0, 2.0]), rotation=np.eye(3))
    pts = np.random.default_rng(0).uniform(-0.5, 2.5, (3000, 3))
    away = np.min(np.abs(np.concatenate([pts, 2 - pts], axis=1)), axis=1) > 1e-3
    mesh = Mesh(vertices=v, faces=f)
    assert np.array_equal(mesh.inside(pts)[away], box.inside(pts)[away])
    cracked = Mesh(vertices=v, faces=f[:-1])                                   # one triangle missing
    deep = np.all((pts > 0.5) & (pts < 1.5), axis=1)
    assert cracked.inside(pts[deep]).all() and not cracked.inside(pts[np.all(pts < -0.1, axis=1)]).any()
    near = np.array([[1.0, 1.0, 1.99], [1.0, 1.0, 1.0]])
    assert mesh.inside(near).tolist() == [True, True] and mesh.inside(near, margin_m=0.05).tolist() == [False, True]
