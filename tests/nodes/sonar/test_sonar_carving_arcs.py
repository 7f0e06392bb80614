"""Carving's front end (nodes.sonar.carving_arcs): a synthetic ping with known returns, and arcs of known geometry."""
from __future__ import annotations

import math

import numpy as np
import pytest

from nodes.sonar.carving import CarvingParams
from nodes.sonar.carving_arcs import coarsen_ping, extract_returns, sample_arcs
from sim.fls import sonar_frame

SPREAD = math.radians(20.0)
BEARINGS = np.radians(np.linspace(-30.0, 30.0, 61))
DR, ROWS = 0.02, 500                       # 10 m of range


def _ping(*blocks: tuple[float, float, int]) -> np.ndarray:
    """A dark uint8 ping with bright blocks (start m, depth m, beam), three beams wide."""
    img = np.full((ROWS, BEARINGS.size), 5, np.uint8)
    for r0, depth, j in blocks:
        img[int(r0 / DR):int((r0 + depth) / DR), j - 1:j + 2] = 250
    return img


def test_a_bright_target_is_its_beam_s_front_end_and_empties_the_range_before_it() -> None:
    pose = np.eye(4)
    ret = extract_returns(_ping((6.0, 0.1, 30)), BEARINGS, DR, pose, SPREAD, params=CarvingParams(returns="front"))
    assert 1 <= ret.n_front <= 3 and ret.ranges_m.size == ret.n_front          # the target's beam and neighbours
    assert np.all(np.abs(ret.ranges_m - 6.0) < 0.1)
    assert np.all(np.abs(ret.bearings_rad) <= BEARINGS[31] + 1e-9)
    assert abs(ret.free_m[30] - (6.0 - 0.15)) < 0.1                              # up to the front end less margin
    assert np.all(ret.free_m[:25] > 9.0)                                         # no return, no seafloor: all range


def test_all_returns_adds_the_bright_blocks_behind_the_front_end_only() -> None:
    img = _ping((4.0, 0.1, 30), (7.0, 0.3, 30))
    front = extract_returns(img, BEARINGS, DR, np.eye(4), SPREAD, params=CarvingParams(returns="front"))
    every = extract_returns(img, BEARINGS, DR, np.eye(4), SPREAD, params=CarvingParams(returns="all"))
    assert every.n_front == front.n_front
    np.testing.assert_array_equal(every.ranges_m[:every.n_front], front.ranges_m)
    behind = every.ranges_m[every.n_front:]
    assert behind.size > 0 and np.all((behind > 6.9) & (behind < 7.4))          # the far block, not the near one
    assert every.blocks is not None and every.blocks.bright.shape[1] == (BEARINGS.size + 1) // 2


def test_a_seafloor_limits_the_free_range_and_one_above_the_sonar_is_refused() -> None:
    pose = sonar_frame(np.array([0.0, 0.0, -1.0]), 0.0, 0.3)                   # 3 m above the floor, 0.3 rad down
    ret = extract_returns(_ping(), BEARINGS, DR, pose, SPREAD, params=CarvingParams(), seafloor_z_m=-4.0)
    r_emin = 3.0 / math.sin(0.3 + SPREAD / 2)                                    # the centre beam's lower edge: 6.6 m
    assert ret.n_front == 0 and r_emin - 0.6 < ret.free_m[30] < r_emin           # less the guard and margin
    assert np.all(ret.free_m < 9.0)                                              # nothing carved past the floor
    with pytest.raises(ValueError, match="above the seafloor"):
        extract_returns(_ping(), BEARINGS, DR, pose, SPREAD, params=CarvingParams(), seafloor_z_m=0.0)


def test_coarsening_averages_range_pairs_and_makes_floats_finite() -> None:
    img = np.arange(12 * 4, dtype=np.float32).reshape(12, 4) / 48
    img[3, 1] = np.nan
    small, dr, f = coarsen_ping(img, 0.02, 0.1)
    assert (f, dr, small.shape) == (2, 0.04, (6, 4))
    assert np.all(np.isfinite(small)) and small[1, 1] == pytest.approx(0.5 * img[2, 1])     # NaN counts as dark
    assert small[0, 0] == pytest.approx(0.5 * (img[0, 0] + img[1, 0]))
    same, dr1, f1 = coarsen_ping(img, 0.05, 0.1)                                 # cells already > 0.4 voxel
    assert (f1, dr1) == (1, 0.05) and same.shape == img.shape


def test_an_arc_s_samples_lie_at_its_range_across_the_aperture_and_leave_the_grid_counted() -> None:
    pose = np.eye(4)
    pose[:3, 3] = [0.05, 0.05, 0.05]
    grid = dict(grid_origin_m=np.array([-10.0, -10.0, -10.0]), shape=(200, 200, 200), voxel_m=0.1, step_m=0.1)
    s = sample_arcs(np.array([5.0]), np.array([0.0]), pose, SPREAD / 2, **grid)
    assert s.outside == 0 and s.voxel.size == math.ceil(SPREAD * 5.0 / 0.1) + 1
    assert s.phi[0] == pytest.approx(-SPREAD / 2) and s.phi[-1] == pytest.approx(SPREAD / 2)
    ijk = np.stack(np.unravel_index(s.voxel, grid["shape"]), axis=1)
    centres = (ijk + 0.5) * 0.1 + grid["grid_origin_m"]
    assert np.all(np.abs(np.linalg.norm(centres - pose[:3, 3], axis=1) - 5.0) < 0.1)   # on the range sphere
    assert np.all(np.abs(centres[:, 1] - 0.05) < 0.06)                             # in the beam's vertical plane
    assert np.ptp(centres[:, 2]) > 2 * 5.0 * math.sin(SPREAD / 2) - 0.2            # across the whole aperture
    far = sample_arcs(np.array([5.0, 12.0]), np.array([0.0, 0.0]), pose, SPREAD / 2, **grid)
    assert far.outside > 0 and np.all(far.arc == 0)                                # 12 m is past the box's edge
