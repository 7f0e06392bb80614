"""bench/sonar_cloud's audited visible surface (``facing_surface``): the bench's rule counts every structure sample
within 0.1 m of a true first hit, which takes in faces turned away from every sonar position across an edge; the
corrected rule keeps only samples some ping that hit near them sees from the front. The old key keeps its rule."""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[3]
sys.path.insert(0, str(REPO / "bench"))


def test_a_thin_plate_hit_on_its_front_does_not_count_its_back():
    from sonar_cloud import facing_surface

    from nodes.sonar.evaluation import visible_surface

    # a 2 x 2 m plate 0.06 m thick, its front at y = 0 facing the sonar at y = -5, samples every 0.1 m on both faces
    u = np.arange(-1.0, 1.001, 0.1)
    x, z = np.meshgrid(u, u)
    front = np.stack([x.ravel(), np.zeros(x.size), z.ravel()], 1)
    back = front + [0.0, 0.06, 0.0]
    model = np.concatenate([front, back])
    normals = np.concatenate([np.tile([0.0, -1.0, 0.0], (len(front), 1)), np.tile([0.0, 1.0, 0.0], (len(back), 1))])
    rng = np.random.default_rng(0)
    hits = [front + rng.normal(0.0, 0.01, front.shape) for _ in range(3)]      # three pings hit the front only
    origins = [np.array([s, -5.0, 0.5]) for s in (-0.5, 0.0, 0.5)]
    assert len(visible_surface(model, np.concatenate(hits), 0.1)) == len(model)       # the bench's rule: both faces
    facing, audit = facing_surface(model, normals, hits, origins, floor_z_m=-10.0)
    assert len(facing) == len(front) and np.allclose(np.sort(facing, axis=0), np.sort(front, axis=0))
    assert audit["back_facing"] == 0.5 and audit["single_ping"] == 0.0 and audit["near_floor"] == 0.0


def test_the_one_sided_block_keeps_its_seen_faces_and_drops_the_side_the_pass_never_faced():
    """The issue's hard case: one straight pass, the block seen from one side only, a flat seafloor."""
    from sonar_cloud import facing_surface
    from sim.fls import PingSettings, load_scene, render_ping, sample_structures

    scene = load_scene("block")         # box x -0.5..1.5, y 3..5; the track runs north at x = 0, never past it
    rng = np.random.default_rng(3)
    hits, origins = [], []
    for t in np.arange(2.0, 6.0, 0.5):
        pose = scene.sonar_pose(float(t))
        r = render_ping(scene, pose, PingSettings(n_beams=256, range_m=20.0), rng=rng)
        hits.append(r.hits_m[r.hit_labels > 0])
        origins.append(pose[:3, 3])
    model, normals = sample_structures(scene, 0.1)
    facing, audit = facing_surface(model, normals, hits, origins, floor_z_m=scene.seafloor.z_m)
    from nodes.sonar.evaluation import visible_surface
    kept = {tuple(q) for q in np.round(facing, 6)}
    seen = np.concatenate(hits)
    west = normals[:, 0] < -0.9                  # the west face: the sonar at x = 0 stays east of its plane x = -0.5
    old_west = visible_surface(model[west], seen, 0.1)
    assert len(old_west) > 0                                     # the bench's rule counts some of it (at its edges)
    assert not any(tuple(q) in kept for q in np.round(model[west], 6))
    for face in (normals[:, 1] < -0.9, normals[:, 2] > 0.9):     # the south face and the top: all they showed stays
        old_face = visible_surface(model[face], seen, 0.1)
        assert len(old_face) > 20 and all(tuple(q) in kept for q in np.round(old_face, 6))
    assert 0 < audit["back_facing"] < 0.5 and audit["visible"] == len(visible_surface(model, seen, 0.1))
    assert audit["facing"] == len(facing)
