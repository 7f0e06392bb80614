"""Model yaw symmetries found at build time, and what align does with them (whole-circle search)."""
from __future__ import annotations

import math

import numpy as np
import pytest

from nodes.sonar.icp import IcpModel, IcpSettings, align
from nodes.sonar.icp_gate import gate_threshold, mahalanobis_to_prior
from nodes.sonar.icp_localizer import Config, load_model

SCENES = "sim/scenes/fls_{}.yaml"


def _model(name: str, spacing_m: float = 0.1) -> IcpModel:
    pts, nrm = load_model(Config(model=SCENES.format(name) if not name.startswith("tripod") else name,
                                 spacing_m=spacing_m))
    return IcpModel.build(pts, nrm, symmetry=True)


def _yaws(twins) -> list[float]:
    return sorted(round(math.degrees(t.yaw_rad) % 360) for t in twins)


@pytest.mark.parametrize("name, exact", [("pier4", [90, 180, 270]), ("pier4_near", [90, 180, 270]),
                                         ("piles2", [180]), ("wall", [180]), ("tripod_symmetric", [120, 240])])
def test_twins_of_symmetric_models(name: str, exact: list[int]) -> None:
    sym = _model(name, 0.15).symmetry
    assert not sym.continuous
    assert [y for y in _yaws(sym.exact)] == pytest.approx(exact, abs=2)


def test_the_tripod_with_pylons_has_partial_twins_only() -> None:
    sym = _model("tripod", 0.15).symmetry
    assert _yaws(sym.twins) == pytest.approx([120, 240], abs=2) and not sym.exact
    assert all(0.6 < t.match < 0.95 for t in sym.twins)


def test_a_single_pile_is_continuous_and_every_fit_ambiguous() -> None:
    model = _model("cylinder")
    assert model.symmetry.continuous
    rng = np.random.default_rng(0)
    view = model.points[(model.points[:, 0] < 2.0) & (model.points[:, 2] > -5.0)]
    cloud = view[rng.choice(len(view), 300, replace=False)] + [0.2, -0.1, 0.0]
    out = align(cloud, model, settings=IcpSettings(dof="xy_yaw"))
    assert out.ambiguous and out.degenerate


def _view(model: IcpModel, sonar, n: int = 600, seed: int = 0) -> np.ndarray:
    """Model samples facing a sonar within 65 deg of north and 20 m, 2 cm noise."""
    rng = np.random.default_rng(seed)
    v = model.points - np.asarray(sonar)
    keep = (np.einsum("ij,ij->i", -v, model.normals) > 0) & (np.abs(np.degrees(np.arctan2(v[:, 0], v[:, 1]))) < 65)
    keep &= np.linalg.norm(v, axis=1) < 20
    pts = model.points[keep]
    return pts[rng.choice(len(pts), min(n, len(pts)), replace=False)] + rng.normal(0, 0.02, (min(n, len(pts)), 3))


def _turn(yaw_deg: float, shift=(0.3, -0.2)) -> np.ndarray:
    a = math.radians(yaw_deg)
    t = np.eye(4)
    t[:2, :2] = [[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]]
    t[:2, 3] = shift
    return t


@pytest.mark.parametrize("name", ["pier4", "pier4_near"])
def test_a_square_pier_is_ambiguous_with_four_hypotheses_and_the_nearest_to_the_prior_first(name: str) -> None:
    model = _model(name, 0.15)
    off = _turn(20.0)                                     # navigation 20 deg off
    cloud = _view(model, (0.0, -12.0, -1.5)) @ off[:3, :3].T + off[:3, 3]
    out = align(cloud, model, settings=IcpSettings(dof="xy_yaw"))
    assert out.ambiguous and len(out.hypotheses) == 4
    yaws = sorted(math.degrees(math.atan2(t[1, 0], t[0, 0])) % 360 for _, t in out.hypotheses)
    assert np.allclose(np.diff(yaws), 90.0, atol=2.0), yaws
    c = out.transform @ off                               # the one given is the right one (20 deg back)
    assert abs(math.degrees(math.atan2(c[1, 0], c[0, 0]))) < 1.0


def test_a_wall_leaves_its_length_unobserved_and_the_covariance_says_so() -> None:
    model = _model("wall", 0.2)
    cloud = _view(model, (0.0, 0.0, -1.0), n=800) + [0.3, 0.2, 0.0]
    out = align(cloud, model, settings=IcpSettings(dof="xy_yaw"))
    assert out.degenerate and out.ambiguous                        # and 180 deg twin (the far side)
    cov = out.covariance
    assert cov[0, 0] > 1e3 and cov[1, 1] < 1e-2                     # along the wall (x): unknown; across: known
    assert abs(out.transform[1, 3] + 0.2) < 0.05                    # the observable part is corrected


def test_the_navigation_gate_passes_20_deg_and_rejects_90_deg() -> None:
    pivot = np.array([0.0, 0.0, -4.0])
    thr = gate_threshold(0.99)
    kw = dict(sigma_m=2.0, sigma_yaw_rad=math.radians(15.0))
    assert mahalanobis_to_prior(_turn(20.0, (1.0, 0.5)), np.zeros((6, 6)), pivot, **kw) < thr
    assert mahalanobis_to_prior(_turn(90.0, (0.0, 0.0)), np.zeros((6, 6)), pivot, **kw) > thr
    assert mahalanobis_to_prior(np.eye(4), np.full((6, 6), np.nan), pivot, **kw) == 0.0
    with pytest.raises(ValueError, match="confidence"):
        gate_threshold(1.0)
