"""Train and check carving's evidence filter (nodes.sonar.carving_filter) on simulated passes with ground truth.

Training passes (10 pings/s, 512 beams, 20 m, true poses, as bench/sonar_cloud.py): the tripod at another noise
seed and half a ping later than the demo, its return leg from the north, and three other tracks over it (moved east
or west, deeper); the square pier and the two piles (the 20 s of bench/sonar_cloud.py, the 20 s after them, past
the structure, and one moved track each), the single pile, the wall, the one-sided block (6 s) and a second, yawed
box (13 s) -- these 15 all run north --; and (TRAIN_MORE) 11 passes over shapes none of those has, at headings east,
south and west and depths 1.0-2.6 m: a table (a deck on four vertical legs) skimmed 0.2 m above its deck, crossed
higher, beside it below the deck's level and southward; three horizontal pipes at three heights; a vertical plate
facing the track and beside it; the tripod eastward, the square pier eastward and deeper, the two piles southward.
The demo pass itself (tripod, seed 0, ``make demo``) is never trained on: it is the held-out check. Each voted
voxel off the seafloor is labelled by its distance to the structure's surface (<= 0.2 m: on it); the classifier is
scikit-learn's HistGradientBoostingClassifier (depth 3, 60 trees) over MODEL_FEATURES (every evidence feature but
the height above the seafloor), each pass weighted alike.

The threshold is calibrated on passes the model did not see: each training pass is scored by the same recipe
trained without it (leave-one-pass-out), and the threshold kept is the lowest at which at most 10 % of them (2 of
26) keep points less accurate than that pass's default cloud by more than 2 points (within 0.2 m). The rule before
(the 15 northward passes, the height feature) was the lowest probability at which every training pass, scored by
the model trained on it, kept >= 90 % within 0.2 m: 0.77.

``--fresh`` trains nothing: it scores the shipped model (nodes/sonar/carving_filter.json, at its own threshold) beside
the default cloud (``keep="sigma"``, the node's ``max_sigma_m`` 0.3) on passes that neither the first filter's
training, its feature choice nor any carving parameter had seen (FRESH: tracks at other headings, the four-legged
jacket, new noise seeds). Both clouds come from the same pings. Its jacket_eastward pass (the first filter: 69.6 %
within 0.2 m against the default's 88.1 %) informed this version: the diagnosis, the new training shapes and the
dropped height feature. ``--fresh2`` is the new never-seen set, written down before its first run (FRESH2: an
overhanging platform, a sloped plate, a pipe rack, the tripod and the square pier at new headings and depths;
see below). ``--old-model`` scores another model JSON (the first filter) beside the shipped one on the same pings.

The rule for making ``keep: evidence`` the node's default, fixed before the first --fresh2 run: on the demo pass
>= 90 % of points within 0.2 m and >= 70 % completeness at <= 5 ms per 512-beam ping (bench/sonar_cloud.py), and on
every --fresh2 pass an accuracy (within 0.2 m) no more than 2 points below the default cloud's on the same pings.

``--stack`` (measured, not shipped): a second stage that gives the classifier its neighbours' first-stage scores
(stacking). Its inputs: MODEL_FEATURES and, over the other voted voxels of the 3 x 3 x 3 and 5 x 5 x 5 blocks and of
the 3 x 3 column 0.2-1.0 m up and down (a ghost and the surface share elevation arcs, near-vertical at the
structure), how many have a first-stage probability >= 0.5, their most and mean probability, how many there are; the
voxel's own probability and that less its column's most probable (:func:`neighbour_context`). Same protocol: the
second stage learns from each training pass's out-of-fold first-stage probabilities (the first stage trained
without that pass; on new passes it reads the full first stage's), its threshold by the rule above over the
training passes each left out of the second stage too (the first-stage probabilities of the others came from
models that saw the left-out pass: a second-order leak, said here), then demo, --fresh and --fresh2 scored beside
the first stage and the default cloud from the same pings. ``rivals``: the same with each voxel's arc rivals too
(:class:`ArcRivalGrid`: the near-best voxels >= 0.25 m away on the arcs that voted for it -- a ghost competes with
the surface on the same arcs --; the most probable one, how many are voted, how many >= 0.5, :func:`arc_rivals`).
Run of 2026-11-28 (load ~1.0 on 2 cores; within 0.2 m % / completeness %, at each one's training-chosen threshold):

    pass / threshold     default      first 0.85   second 0.82  rivals 0.81  best at >= 90 %, swept on the pass itself
    demo                 93.4 / 49.9  95.3 / 59.2  95.0 / 57.5  94.7 / 59.6  first 68.7, second 69.7, rivals 69.96
    --fresh completeness up on (vs first)          3 of 6       6 of 6       accuracy down (vs first) on 4 and 4 of 6
    --fresh2 completeness up on (vs first)         7 of 8       8 of 8       accuracy down (vs first) on 3 and 4 of 8
    > 2 points less accurate than the default: first 0 / 2 (fresh / fresh2: overhang_300_under, pipe_rack_160);
    second 1 / 2 (jacket_eastward / overhang_030, pipe_rack_250); rivals 2 / 3 (jacket, jacket_eastward /
    overhang_030, pipe_rack_250, pipe_rack_160)

Training passes left out: median completeness 66.0 (first), 69.2 (second), 70.6 % (rivals) at 94.3 / 93.7 / 93.7 %
within 0.2 m. Time: 41 ms (second) and 54 ms (rivals) per cloud, median over the 15 passes (context through a dense
padded copy of the grid, not optimised, and scikit-learn's trees; the rivals also need the arcs' near-best voxels
recorded at each vote): a cloud every 10th ping adds 4-5 ms per ping averaged, past the 5 ms budget beside carving's
1.3-4.0. Neither meets the default-switch rule (demo completeness 57.5 / 59.6 % < 70 %; 2 and 3 --fresh2 passes
more than 2 points below the default) nor is better on the held-out passes at the threshold the training chose
(more completeness, less accuracy: the same trade further along, and the demo about even), so neither is shipped:
the node's filter is the first stage alone. Before this run three variants were tried on the same passes (a 5 x 5 x 5
shell that also left out the voxel's 8 in-plane neighbours; the context alone without the evidence; the 3 x 3 x 3
block and column only: demo 94.4 / 59.0, 95.2 / 56.0, 97.8 / 54.7 at their training-chosen 0.81, 0.82, 0.84) and
the first stage's evidence with the rivals but no neighbour context (0.86: 96.0 / 57.4, best at >= 90 % 70.6 %;
jacket_eastward and overhang_300_under > 2 points below the default).

``--calibrated`` (measured, not shipped): a threshold per pass from the model's own calibrated probabilities, no
ground truth of the pass scored (carving_filter.keep_calibrated, ``select(keep_rule="calibrated")``): an isotonic
map from probability to on-surface fraction fitted on the 26 training passes' out-of-fold probabilities (each pass
alike; exported by ``--write`` into carving_filter.json beside the trees, which it does not change), then on a pass
the voxels kept in decreasing calibrated probability while their mean stays >= a target precision; the target by the
threshold's rule above over the training passes, each left out of both training and calibration: 0.905 (the rule and
its variant, isotonic, were fixed on the training passes before any demo/--fresh/--fresh2 pass was scored; Platt
scaling, the raw probabilities and an EM prior-shift re-weighting (Saerens 2002) of the isotonic map were tried on
the training passes only, in a side script not kept here: median completeness 61.0, 61.3 % and, for the EM one, no
target met the rule; the isotonic 61.7 %, the global threshold 66.0 %). Run of 2026-11-28 (within 0.2 m % /
completeness %):

    pass                 default      global 0.85  calibrated (its threshold, predicted/observed precision)
    demo                 93.4 / 49.9  95.3 / 59.2  96.2 / 54.6  (0.870, 0.924 / 0.962)   best swept: 68.7 at 0.775
    --fresh  more complete than global on 0 of 6; > 2 points below the default: global none, calibrated none
    --fresh2 more complete than global on 4 of 8; > 2 points below the default: global overhang_300_under,
             pipe_rack_160; calibrated overhang_030, overhang_300_under, sloped_plate_120

The calibration does not hold across passes, which is why: on the training passes each left out, the share of the
voxels kept at 0.85 predicted on the surface by the calibrated map spans 0.880-0.929, the share observed
0.584-1.000, and the two correlate at -0.51 across passes -- the model is most confident on the passes where it is
least right (pier4_north 0.929 predicted / 0.584 observed, table_south 0.929 / 0.843, pipes_east_deep 0.926 / 0.869;
plate_east 0.901 / 1.000). So the per-pass threshold lands at 0.87 on most passes (a step of the isotonic map),
lower where many voxels look sure (0.79-0.80 on table_south, pipes_east_deep and the overhangs and sloped plates of
--fresh2, which lose accuracy), and never near the 0.775 the demo would allow. Training passes left out: median
95.5 % within 0.2 m / completeness 61.7 % (global 94.3 / 66.0). The rule costs 0.76-0.85 ms per cloud (median over
the 15 scored passes, two runs; a sort of the cloud's voxels: < 0.1 ms per ping at a cloud every 10th). A ceiling
for any per-pass threshold of this model: chosen on the demo with its own ground truth, the lowest threshold at the
training's criterion (no more than 2 points below the default) is 0.795, 92.0 % / 67.0 %, and the best at >= 90 %
within 0.2 m 68.7 % (0.775): no threshold of this model, however chosen, gives the demo 70 %; the limit is the
model's ranking. Neither the goal (demo 54.6 % < 70 %) nor the default-switch rule (3 --fresh2 passes > 2 points
below the default) is met: the node's default stays the global threshold.

    python bench/sonar_carving_filter.py [--write] [--json]      # --write: nodes/sonar/carving_filter.json
    python bench/sonar_carving_filter.py --demo --fresh --fresh2 [--old-model M.json] [--json]
    python bench/sonar_carving_filter.py --stack [--json]        # the second stage, trained and scored
    python bench/sonar_carving_filter.py --calibrated [--json]   # a threshold per pass, trained and scored
"""
from __future__ import annotations

import os

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ[_var] = "1"

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import numpy as np  # noqa: E402

from nodes.sonar import carving_filter  # noqa: E402
from nodes.sonar.carved_cloud import Config as CarvedCloudConfig  # noqa: E402
from nodes.sonar.carving import CarvingGrid, CarvingParams  # noqa: E402
from nodes.sonar.evaluation import cloud_metrics, surface_distances, visible_surface  # noqa: E402

BOUNDS = ((-12, -12, -6.5), (12, 12, 0.0))
DEFAULT_SIGMA_M = CarvedCloudConfig().max_sigma_m     # the published cloud's sigma rule
# name: (scene, first s, last s, noise seed)
# a second box, longer, yawed and nearer the track than the one-sided block (training only)
BOX2 = {"name": "box2", "seafloor": {"type": "plane", "z_m": -6.0},
        "structures": [{"type": "box", "center_m": [-2.0, 6.0, -5.0], "size_m": [3.0, 1.2, 2.0], "yaw_deg": 30}],
        "sonar": {"tilt_deg": 15}, "platform": {"start_m": [0.0, -8.0], "end_m": [0.0, 12.0], "depth_m": 1.0,
                                                "speed_mps": 1.5}}


def track(name: str | dict, start_m: list[float], end_m: list[float], depth_m: float) -> dict:
    """Scene ``name`` (or a scene dict) with a straight track from ``start_m`` to ``end_m`` at ``depth_m``."""
    from tether.yamlsafe import load_yaml_file

    scene = dict(name) if isinstance(name, dict) else dict(load_yaml_file(ROOT / "sim" / "scenes" / f"fls_{name}.yaml"))
    scene["platform"] = dict(scene["platform"], start_m=start_m, end_m=end_m, depth_m=depth_m)
    return scene


def moved_track(name: str, x_m: float, depth_m: float) -> dict:
    """Scene ``name`` with its straight northward track moved to ``x_m`` east at ``depth_m``."""
    return track(name, [x_m, -30.0], [x_m, 30.0], depth_m)


TRAIN = {"tripod_seed1": ("tripod", 0.05, 20.0, 1), "tripod_back": ("tripod", 40.0, 60.0, 0),
         "tripod_west": (moved_track("tripod", -1.5, 1.0), 0.0, 20.0, 4),
         "tripod_deep": (moved_track("tripod", 1.0, 2.0), 0.0, 20.0, 5),
         "tripod_east": (moved_track("tripod", 3.0, 1.5), 0.0, 20.0, 6),
         "pier4_west": (moved_track("pier4", -1.0, 1.0), 0.0, 20.0, 7),
         "piles2_deep": (moved_track("piles2", 1.0, 2.0), 0.0, 20.0, 8),
         "cylinder": ("cylinder", 0.0, 20.0, 9),
         "pier4": ("pier4", 0.0, 20.0, 0), "pier4_north": ("pier4", 20.0, 40.0, 2),
         "piles2": ("piles2", 0.0, 20.0, 0), "piles2_north": ("piles2", 20.0, 40.0, 2),
         "wall": ("wall", 0.0, 20.0, 0), "block": ("block", 0.0, 6.0, 0), "box2": (BOX2, 0.0, 13.0, 3)}
HELD_OUT = {"tripod_demo": ("tripod", 0.0, 20.0, 0)}


def _scene(name: str, structures: list[dict]) -> dict:
    """A scene on the 6 m flat seafloor with the demo's sonar (its platform set by :func:`heading_track`)."""
    return {"name": name, "seafloor": {"type": "plane", "z_m": -6.0, "reflectivity": 0.3}, "structures": structures,
            "sonar": {"tilt_deg": 15, "frequency": "low"},
            "platform": {"start_m": [0.0, -30.0], "end_m": [0.0, 30.0], "depth_m": 1.0, "speed_mps": 1.5}}


def _cyl(name: str, a: list[float], b: list[float], radius_m: float, refl: float = 0.85) -> dict:
    return {"type": "cylinder", "name": name, "from_m": a, "to_m": b, "radius_m": radius_m, "reflectivity": refl}


def _box(name: str, centre: list[float], size: list[float], refl: float = 0.8, **angles_deg: float) -> dict:
    return {"type": "box", "name": name, "center_m": centre, "size_m": size, "reflectivity": refl, **angles_deg}


# a four-legged jacket (legs leaning in, X braces on two faces, a deck stub): no scene has this shape
JACKET = _scene("jacket", [_cyl(f"leg_{c}", [3.5 * sx, 3.5 * sy, -6.0], [2.0 * sx, 2.0 * sy, -2.0], 0.35, 0.9)
                           for c, sx, sy in (("ne", 1, 1), ("nw", -1, 1), ("sw", -1, -1), ("se", 1, -1))]
                + [_cyl("x_s1", [-3.3, -3.3, -5.5], [2.2, -2.2, -2.5], 0.2),
                   _cyl("x_s2", [3.3, -3.3, -5.5], [-2.2, -2.2, -2.5], 0.2),
                   _cyl("x_w1", [-3.3, -3.3, -5.5], [-2.2, 2.2, -2.5], 0.2),
                   _cyl("x_w2", [-3.3, 3.3, -5.5], [-2.2, -2.2, -2.5], 0.2),
                   _box("deck", [0.0, 0.0, -1.8], [4.6, 4.6, 0.4], yaw_deg=0)])
# name: (scene, first s, last s, noise seed); 1.5 m/s tracks, 20 s = 30 m
FRESH = {"tripod_diagonal": (track("tripod", [-16.0, -18.0], [14.0, 12.0], 1.2), 0.0, 20.0, 21),
         "tripod_westward": (track("tripod", [16.0, 1.0], [-24.0, 1.0], 1.0), 0.0, 20.0, 22),
         "pier4_southward": (track("pier4", [1.5, 22.0], [1.5, -30.0], 1.2), 0.0, 20.0, 23),
         "piles2_diagonal": (track("piles2", [15.0, -17.0], [-15.0, 13.0], 1.0), 0.0, 20.0, 24),
         "jacket": (track(JACKET, [-1.0, -20.0], [-1.0, 30.0], 1.0), 0.0, 20.0, 25),
         "jacket_eastward": (track(JACKET, [-20.0, 0.5], [30.0, 0.5], 1.5), 0.0, 20.0, 26)}


def heading_track(scene: str | dict, heading_deg: float, through_m: tuple[float, float], depth_m: float) -> dict:
    """Scene with a straight 1.5 m/s track at ``heading_deg`` (0 north, 90 east) through ``through_m`` (x, y),
    starting 16 m before it (a 20 s pass: 30 m, ending 14 m past it)."""
    h = np.radians(heading_deg)
    u = np.array([np.sin(h), np.cos(h)])
    c = np.asarray(through_m, float)
    return track(scene, (c - 16.0 * u).round(3).tolist(), (c + 24.0 * u).round(3).tolist(), depth_m)


# training shapes beside the scenes' (decks, plates, horizontal members; no jacket, overhang, sloped plate or rack):
# a table -- a 4 x 3 m deck 0.3 m thick, top 2.15 m deep, on four vertical legs --, three horizontal pipes at
# three heights (across, along and diagonal to a northward track), a vertical plate standing on the seafloor
TABLE = _scene("table", [_box("deck", [0.0, 0.0, -2.3], [4.0, 3.0, 0.3])]
               + [_cyl(f"leg{i}", [x, y, -6.0], [x, y, -2.45], 0.25, 0.9)
                  for i, (x, y) in enumerate(((-1.8, -1.3), (1.8, -1.3), (1.8, 1.3), (-1.8, 1.3)))])
PIPES = _scene("pipes", [_cyl("across", [-5.0, 2.0, -4.0], [5.0, 2.0, -4.0], 0.3),
                         _cyl("along", [2.0, -5.0, -3.0], [2.0, 5.0, -3.0], 0.25),
                         _cyl("diagonal", [-4.0, -4.0, -5.2], [3.0, 3.0, -5.2], 0.35)])
PLATE = _scene("plate", [_box("plate", [0.0, 2.0, -4.5], [4.0, 0.2, 3.0], 0.85)])
# more training passes: the new shapes and the scenes' at headings east, south and west and other depths
TRAIN_MORE = {"table_north_skim": (heading_track(TABLE, 0.0, (0.5, 0.0), 1.95), 0.0, 20.0, 31),
              "table_east_high": (heading_track(TABLE, 90.0, (0.0, 0.8), 1.0), 0.0, 20.0, 32),
              "table_west_beside": (heading_track(TABLE, 270.0, (0.0, -3.0), 2.6), 0.0, 20.0, 33),
              "table_south": (heading_track(TABLE, 180.0, (-0.8, 0.0), 1.5), 0.0, 20.0, 34),
              "pipes_north": (heading_track(PIPES, 0.0, (0.0, 0.0), 1.0), 0.0, 20.0, 35),
              "pipes_east_deep": (heading_track(PIPES, 90.0, (0.0, -1.0), 2.0), 0.0, 20.0, 36),
              "plate_north": (heading_track(PLATE, 0.0, (0.5, 0.0), 1.0), 0.0, 20.0, 37),
              "plate_east": (heading_track(PLATE, 90.0, (0.0, -2.0), 1.5), 0.0, 20.0, 38),
              "tripod_eastward": (heading_track("tripod", 90.0, (0.0, 1.0), 1.5), 0.0, 20.0, 39),
              "pier4_eastward_deep": (heading_track("pier4", 90.0, (0.0, 0.0), 2.2), 0.0, 20.0, 40),
              "piles2_southward": (heading_track("piles2", 180.0, (0.5, 0.0), 1.2), 0.0, 20.0, 30)}
# --fresh2 (written down before its first run; nothing here is trained, chosen or looked at before the final model):
# three shapes no training or --fresh scene has -- an overhanging platform (a deck cantilevered 4.5 m off one
# column, a strut under it), a sloped plate (25 deg pitch, resting near the seafloor), a pipe rack (six posts, two
# stringers, three cross beams, three pipes on top) -- and the tripod and square pier at an altitude and heading no
# pass has; headings 30, 60, 120, 160, 200, 250, 300, 340 deg (training: 0, 90, 180, 270; --fresh 45, 225, 270, 315,
# 90, 0, 180), depths 0.6-3.0 m (training 1.0-2.6)
OVERHANG = _scene("overhang", [_cyl("column", [-2.0, 0.0, -6.0], [-2.0, 0.0, -2.4], 0.5, 0.9),
                               _box("deck", [0.5, 0.0, -2.2], [6.0, 3.5, 0.4]),
                               _cyl("strut", [-2.0, 0.0, -4.0], [1.5, 0.0, -2.45], 0.2)])
SLOPED_PLATE = _scene("sloped_plate", [_box("plate", [0.0, 0.0, -4.8], [4.5, 3.0, 0.15], 0.85, pitch_deg=25.0,
                                            yaw_deg=20.0)])
PIPE_RACK = _scene("pipe_rack", [_cyl(f"post{i}", [x, y, -6.0], [x, y, -2.75], 0.2, 0.9)
                                 for i, (x, y) in enumerate((a, b) for a in (-3.0, 0.0, 3.0) for b in (-1.0, 1.0))]
                   + [_box(f"stringer{i}", [0.0, y, -2.6], [6.4, 0.3, 0.3]) for i, y in enumerate((-1.0, 1.0))]
                   + [_box(f"cross{i}", [x, 0.0, -2.6], [0.3, 2.3, 0.3]) for i, x in enumerate((-3.0, 0.0, 3.0))]
                   + [_cyl(f"pipe{i}", [-4.0, y, -2.25], [4.0, y, -2.25], 0.2) for i, y in enumerate((-0.6, 0.0, 0.6))])
FRESH2 = {"overhang_030": (heading_track(OVERHANG, 30.0, (0.5, 0.8), 1.7), 0.0, 20.0, 41),
          "overhang_300_under": (heading_track(OVERHANG, 300.0, (2.0, -3.5), 3.0), 0.0, 20.0, 42),
          "sloped_plate_120": (heading_track(SLOPED_PLATE, 120.0, (0.5, 1.0), 2.2), 0.0, 20.0, 43),
          "sloped_plate_340": (heading_track(SLOPED_PLATE, 340.0, (-1.5, 0.0), 1.0), 0.0, 20.0, 44),
          "pipe_rack_250": (heading_track(PIPE_RACK, 250.0, (0.0, 0.4), 1.2), 0.0, 20.0, 45),
          "pipe_rack_160": (heading_track(PIPE_RACK, 160.0, (1.0, 0.0), 1.6), 0.0, 20.0, 46),
          "tripod_200_high": (heading_track("tripod", 200.0, (1.5, 0.0), 0.6), 0.0, 20.0, 47),
          "pier4_060_low": (heading_track("pier4", 60.0, (0.0, 0.0), 2.5), 0.0, 20.0, 48)}
THRESHOLDS = np.round(np.arange(0.5, 0.96, 0.01), 2)
TRAIN_ALL = {**TRAIN, **TRAIN_MORE}
# the features the shipped model reads: not the height above the seafloor (it taught the model where the training
# scenes' structures stand: a deck 4.4 m up, seen briefly, was dropped as a ghost on the jacket)
MODEL_FEATURES = tuple(f for f in carving_filter.FEATURES if f != "height_m")
COLS = [carving_filter.FEATURES.index(f) for f in MODEL_FEATURES]
WORSE_BY = 0.02         # the threshold rule: a pass left out of training may lose this much accuracy vs the default
MAY_LOSE = 0.10         # ... on at most this share of the training passes


def carve_pass(scene_spec, t0: float, t1: float, seed: int, *, rivals: bool = False):
    """Render one pass (10 pings/s, 512 beams, 20 m, true poses) and carve it with ``keep="evidence"`` (which counts
    what the features need; the counts it adds change neither the votes nor the scores the default cloud reads);
    ``rivals``: with an :class:`ArcRivalGrid` (same carving and votes). Returns the flushed grid, the structure's
    surface (3 cm samples) and the part of it the pass saw."""
    from sim.fls import PingSettings, load_scene, render_ping, sample_structures

    scene = load_scene(scene_spec)
    grid = (ArcRivalGrid if rivals else CarvingGrid)(BOUNDS, CarvingParams(keep="evidence"), seafloor_z_m=scene.seafloor.z_m)
    rng, hits = np.random.default_rng(seed), []
    for t in np.arange(t0, t1, 0.1):
        pose = scene.sonar_pose(float(t))
        r = render_ping(scene, pose, PingSettings(n_beams=512, range_m=20.0), rng=rng)
        hits.append(r.hits_m[r.hit_labels > 0])
        grid.integrate(r.intensities, r.bearings_rad, r.range_resolution_m, pose, r.vertical_aperture_rad)
    grid.flush()
    surface, _ = sample_structures(scene, 0.03)
    model, _ = sample_structures(scene, 0.1)
    return grid, surface, visible_surface(model, np.concatenate(hits), 0.1)


def voted(grid: CarvingGrid) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray], np.ndarray]:
    """The grid's voted voxels off the seafloor (what CarvingGrid.cloud scores): rows, points, evidence (every name
    of carving_filter.FEATURES), and whether the default cloud (``keep="sigma"``, ``max_sigma_m`` DEFAULT_SIGMA_M)
    keeps each."""
    rows = grid.off_floor(grid.voted_rows())
    ev = carving_filter.evidence(grid, rows, carving_filter.plausible_rows(grid))
    return rows, grid.candidate_points()[rows], ev, grid.default_keep(rows, max_sigma_m=DEFAULT_SIGMA_M)


def run_pass(scene_spec, t0: float, t1: float, seed: int, *, rivals: bool = False) -> dict:
    """Carve one pass; every voted voxel off the seafloor with its features, its distance to the surface, whether
    the default cloud keeps it, and the surface the pass saw (``rivals``: and its arc rivals, ArcRivalGrid.pairs)."""
    grid, surface, visible = carve_pass(scene_spec, t0, t1, seed, rivals=rivals)
    rows, pts, ev, default = voted(grid)
    on = surface_distances(pts, surface) <= 0.2
    return dict(x=carving_filter.feature_matrix(ev), points=pts, on=on, default=default,
                default_acc=float(np.mean(on[default])) if default.any() else 1.0, surface=surface, visible=visible,
                voxels=grid._cand[rows], shape=grid.shape, pairs=grid.pairs() if rivals else None)


def fresh_pass(scene_spec, t0: float, t1: float, seed: int, models: dict[str, dict]) -> dict:
    """One never-seen pass carved once: the default cloud's points and each evidence model's (as CarvingGrid.cloud
    keeps them with that model), from the same grid."""
    grid, surface, visible = carve_pass(scene_spec, t0, t1, seed)
    _, pts, ev, default = voted(grid)
    x = carving_filter.feature_matrix(ev)
    out = {"default": cloud_metrics(pts[default], surface, visible)}
    for name, model in models.items():
        out[name] = cloud_metrics(pts[carving_filter.surface_probability(x, model) >= model["threshold_p"]],
                                  surface, visible)
    return out


def fresh(sets: dict[str, dict], old_model: str | None, as_json: bool) -> None:
    """--fresh / --fresh2 / --demo: the shipped model (and ``old_model``) beside the default cloud, nothing trained
    or chosen."""
    models = {"evidence": carving_filter.load_model()}
    if old_model:
        models["evidence_old"] = carving_filter.load_model.__wrapped__(old_model)
    out = {"threshold_p": models["evidence"]["threshold_p"],
           "models": {k: {"threshold_p": m["threshold_p"], "features": list(m["features"])} for k, m in models.items()},
           "sets": {}}
    keys = ["default", *models]
    print(f"{'pass':>20} " + "   ".join(f"{k + ': pts':>16} {'<=0.2 m %':>9} {'complete %':>10}" for k in keys))
    for set_name, passes in sets.items():
        res = out["sets"][set_name] = {"passes": {}}
        for name, spec in passes.items():
            print(f"  carving {name}", file=sys.stderr, flush=True)
            m = res["passes"][name] = fresh_pass(*spec, models)
            print(f"{name:>20} " + "   ".join(f"{m[k]['points']:16d} {100 * m[k]['acc_frac_0p2']:9.1f} "
                                                f"{100 * m[k]['completeness_0p2']:10.1f}" for k in keys))
        for k in keys:
            acc = [m[k]["acc_frac_0p2"] for m in res["passes"].values()]
            comp = [m[k]["completeness_0p2"] for m in res["passes"].values()]
            worse = [n for n, m in res["passes"].items() if m[k]["acc_frac_0p2"] < m["default"]["acc_frac_0p2"] - WORSE_BY]
            res[k] = {"acc_frac_0p2_median": float(np.median(acc)),
                                "completeness_0p2_median": float(np.median(comp)),
                                "passes_acc_ge_0p9": int(sum(a >= 0.9 for a in acc)), "passes": len(acc),
                                "passes_acc_below_default_by_2": worse}
            print(f"{set_name} {k}: median within 0.2 m {100 * np.median(acc):.1f} %, median completeness "
                  f"{100 * np.median(comp):.1f} %, >= 90 % within 0.2 m on {sum(a >= 0.9 for a in acc)} of "
                  f"{len(acc)}; more than 2 points less accurate than the default on {worse or 'none'}")
    if "fresh" in out["sets"]:                # the keys bench/readme.py's row reads: --fresh as before
        out.update({k: out["sets"]["fresh"][k] for k in ("passes", "default", "evidence")})
    if as_json:
        print(json.dumps(out))


def fit(passes: list[dict]):
    from sklearn.ensemble import HistGradientBoostingClassifier

    x = np.concatenate([p["x"][:, COLS] for p in passes])
    y = np.concatenate([p["on"] for p in passes])
    w = np.concatenate([np.full(len(p["on"]), 1e4 / len(p["on"])) for p in passes])      # each pass alike
    return HistGradientBoostingClassifier(max_depth=3, max_iter=60, learning_rate=0.1, random_state=0).fit(x, y,
                                                                                                    sample_weight=w)


def probability(clf, d: dict) -> np.ndarray:
    return clf.predict_proba(d["x"][:, COLS])[:, 1]


def score(prob: np.ndarray, d: dict, threshold: float) -> dict:
    return cloud_metrics(d["points"][prob >= threshold], d["surface"], d["visible"])


def choose_threshold(passes: list[dict], held_out_probs: list[np.ndarray]) -> float:
    """The lowest threshold at which at most MAY_LOSE of the passes, each scored by the model trained without it,
    keep points less accurate (within 0.2 m) than their default cloud by more than WORSE_BY."""
    for t in THRESHOLDS:
        worse = [np.mean(p["on"][q >= t]) < p["default_acc"] - WORSE_BY for p, q in zip(passes, held_out_probs)
                 if np.any(q >= t)]
        if sum(worse) <= MAY_LOSE * len(passes):
            return float(t)
    return float(THRESHOLDS[-1])



# -- --calibrated: a threshold per pass from calibrated probabilities (carving_filter.keep_calibrated) -------------
CAL_TARGETS = np.round(np.arange(0.80, 0.995, 0.005), 3)
RELIABILITY_BINS = (0.5, 0.8, 0.9, 0.95, 1.0)


def fit_calibration(passes: list[dict], probs: list[np.ndarray]):
    """Isotonic map from the model's probability to the on-surface fraction, fitted on ``probs`` (each pass's
    out-of-fold probabilities), each pass weighted alike (as the classifier's training)."""
    from sklearn.isotonic import IsotonicRegression

    w = np.concatenate([np.full(len(p["on"]), 1e4 / len(p["on"])) for p in passes])
    return IsotonicRegression(y_min=0.0, y_max=1.0, out_of_bounds="clip").fit(
        np.concatenate(probs), np.concatenate([p["on"] for p in passes]), sample_weight=w)


def choose_target(passes: list[dict], held_out_probs: list[np.ndarray]) -> tuple[float, list]:
    """The lowest CAL_TARGETS target precision at which at most MAY_LOSE of the passes lose more than WORSE_BY of
    accuracy (within 0.2 m) against their default cloud (the threshold's rule), each pass scored by the model
    trained without it and calibrated on the others' out-of-fold probabilities (nested: the calibration never saw
    the pass; those probabilities came from models that did, a second-order leak). Returns it and, per pass, the
    calibration map used."""
    maps = [carving_filter.calibration_map(fit_calibration(passes[:i] + passes[i + 1:],
                                                           held_out_probs[:i] + held_out_probs[i + 1:]))
            for i in range(len(passes))]
    for target in CAL_TARGETS:
        worse = 0
        for p, q, m in zip(passes, held_out_probs, maps):
            keep = carving_filter.keep_calibrated(q, m, target_precision=float(target)).keep
            worse += bool(keep.any()) and np.mean(p["on"][keep]) < p["default_acc"] - WORSE_BY
        if worse <= MAY_LOSE * len(passes):
            return float(target), maps
    return float(CAL_TARGETS[-1]), maps


def reliability(on: np.ndarray, q: np.ndarray, keep_global: np.ndarray) -> dict:
    """Predicted (mean calibrated probability) against observed on-surface fraction: over all voted voxels, over
    those the global threshold keeps, and per RELIABILITY_BINS bin of calibrated probability ([predicted, observed,
    voxels], bins of >= 20 voxels)."""
    def pair(s: np.ndarray) -> list:
        return [float(np.mean(q[s])), float(np.mean(on[s])), int(s.sum())] if s.sum() else [None, None, 0]

    bins = {f"{lo:.2f}-{hi:.2f}": pair(s) for lo, hi in zip(RELIABILITY_BINS[:-1], RELIABILITY_BINS[1:])
            if (s := (q >= lo) & ((q < hi) | (hi == 1.0))).sum() >= 20}
    return {"all": pair(np.ones(len(q), bool)), "at_global_threshold": pair(keep_global), "bins": bins}


# -- --stack: a second stage over the neighbours' first-stage probabilities (measured, not shipped) ---------------
# offsets (di, dj, dk) in voxels: the 3 x 3 x 3 and 5 x 5 x 5 blocks (self left out), and the 3 x 3 column 0.2-1.0 m
# above and below (a ghost and the true point share elevation arcs, which run near-vertical at the structure)
def _block(r: int) -> list[tuple[int, int, int]]:
    """The (2r + 1)^3 block's offsets but the centre."""
    return [(a - r, b - r, c - r) for a, b, c in np.ndindex(2 * r + 1, 2 * r + 1, 2 * r + 1) if (a, b, c) != (r, r, r)]


CONTEXT = {"b3": _block(1), "b5": _block(2),
           "col": [(a, b, c) for a in (-1, 0, 1) for b in (-1, 0, 1) for c in range(-10, 11) if abs(c) >= 2]}
CONTEXT_NAMES = tuple(f"{k}_{s}" for k in sorted(CONTEXT) for s in ("above", "max", "mean", "n")) + ("p1", "p1_minus_col_max")
STACK_FEATURES = MODEL_FEATURES + CONTEXT_NAMES


def neighbour_context(voxels: np.ndarray, shape: tuple[int, int, int], p1: np.ndarray) -> np.ndarray:
    """The second stage's inputs beside the evidence: for each voted voxel (flat ``voxels`` of a grid of ``shape``,
    first-stage probabilities ``p1``), over the other voted voxels of each CONTEXT set: how many are >= 0.5
    (``above``), the most and mean probability (0 without any), how many there are; then ``p1`` and ``p1`` less the
    most probable voxel of its column (a ghost competes with the surface on the same arcs). (K, len(CONTEXT_NAMES))."""
    pad = max(max(abs(v) for o in offs for v in o) for offs in CONTEXT.values())
    dense = np.full(tuple(int(n) + 2 * pad for n in shape), -1.0, np.float32)     # -1: no voted voxel there
    ijk = [i + pad for i in np.unravel_index(np.asarray(voxels, np.int64), tuple(int(n) for n in shape))]
    dense[tuple(ijk)] = p1
    cols, col_max = [], None
    for name in sorted(CONTEXT):
        vals = np.stack([dense[ijk[0] + a, ijk[1] + b, ijk[2] + c] for a, b, c in CONTEXT[name]])
        have = vals >= 0
        n = have.sum(0)
        most = vals.max(0).clip(0.0)
        cols += [(vals >= 0.5).sum(0), most, np.where(have, vals, 0.0).sum(0) / np.maximum(n, 1), n]
        col_max = most if name == "col" else col_max
    return np.column_stack(cols + [p1, p1 - col_max]).astype(np.float64)


class ArcRivalGrid(CarvingGrid):
    """A CarvingGrid that also records, for each arc that votes, its rivals: (winner, near-best voxel of the same arc
    >= 0.25 m from the winner) pairs of flat voxel indices -- a ghost and the surface compete on the same arcs.
    Carving and votes are CarvingGrid's own (the same _vote runs first)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._pairs: list[np.ndarray] = []

    def _vote(self, arcs) -> None:
        super()._vote(arcs)
        p = self.params
        if arcs.voxel.size == 0:
            return
        score = self._score(arcs.voxel)
        starts = np.flatnonzero(np.r_[True, arcs.arc[1:] != arcs.arc[:-1]])
        best = np.repeat(np.maximum.reduceat(score, starts), np.diff(np.r_[starts, arcs.arc.size]))
        ok = best >= p.min_hits
        win, near = np.flatnonzero((score >= best) & ok), np.flatnonzero((score >= p.near_best * best) & ok)
        if win.size == 0:
            return
        lo = np.searchsorted(arcs.arc[near], arcs.arc[win], "left")
        n = np.searchsorted(arcs.arc[near], arcs.arc[win], "right") - lo
        w = np.repeat(win, n)
        other = near[np.repeat(lo, n) + np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)]
        gap = self._centre[self._slot[arcs.voxel[w]]] - self._centre[self._slot[arcs.voxel[other]]]
        far = np.sum(gap ** 2, axis=1) > 0.25 ** 2
        self._pairs.append(np.stack([arcs.voxel[w[far]], arcs.voxel[other[far]]], axis=1))

    def pairs(self) -> np.ndarray:
        """(P, 2) distinct (winner, rival) flat voxel indices."""
        return np.unique(np.concatenate(self._pairs), axis=0) if self._pairs else np.zeros((0, 2), np.int64)


RIVAL_NAMES = ("rival_max", "rival_voted", "rival_above", "p1_minus_rival_max", "rivals")


def arc_rivals(voxels: np.ndarray, pairs: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """For each voted voxel (flat ``voxels``, first-stage ``p1``), over its arc rivals (``pairs`` from
    :meth:`ArcRivalGrid.pairs`) that are voted voxels: the most probable one's probability (0 without any), how many,
    how many >= 0.5, ``p1`` less the most probable; and how many rivals it has, voted or not. (K, len(RIVAL_NAMES))."""
    order = np.argsort(voxels)
    sv = voxels[order]

    def row(v: np.ndarray) -> np.ndarray:                 # the voted voxel's row, -1 if not voted
        i = np.clip(np.searchsorted(sv, v), 0, max(len(sv) - 1, 0))
        return np.where(sv[i] == v, order[i], -1) if len(sv) else np.full(len(v), -1)

    w_all = row(pairs[:, 0])
    w, n = w_all, row(pairs[:, 1])
    ok = (w >= 0) & (n >= 0)
    w, n = w[ok], n[ok]
    most = np.zeros(len(voxels))
    np.maximum.at(most, w, p1[n])
    return np.column_stack([most, np.bincount(w, minlength=len(voxels)).astype(float),
                            np.bincount(w, weights=(p1[n] >= 0.5).astype(float), minlength=len(voxels)),
                            p1 - most, np.bincount(w_all[w_all >= 0], minlength=len(voxels)).astype(float)])


def stack_x_rivals(d: dict, p1: np.ndarray) -> np.ndarray:
    """:func:`stack_x` and then RIVAL_NAMES."""
    return np.column_stack([stack_x(d, p1), arc_rivals(d["voxels"], d["pairs"], p1)])


def stack_x(d: dict, p1: np.ndarray) -> np.ndarray:
    """A pass's second-stage matrix: MODEL_FEATURES then CONTEXT_NAMES (first-stage probabilities ``p1``)."""
    return np.column_stack([d["x"][:, COLS], neighbour_context(d["voxels"], d["shape"], p1)])


def fit_x(xs: list[np.ndarray], ys: list[np.ndarray]):
    from sklearn.ensemble import HistGradientBoostingClassifier

    w = np.concatenate([np.full(len(y), 1e4 / len(y)) for y in ys])                    # each pass alike
    return HistGradientBoostingClassifier(max_depth=3, max_iter=60, learning_rate=0.1, random_state=0).fit(
        np.concatenate(xs), np.concatenate(ys), sample_weight=w)


STACK_SWEEP = np.round(np.arange(0.3, 0.99, 0.0125), 4)


def completeness_at_acc90(d: dict, prob: np.ndarray) -> tuple[float, float | None]:
    """The best completeness over STACK_SWEEP thresholds with >= 90 % of the kept points within 0.2 m, and that
    threshold (chosen on the pass itself: the trade, not a result)."""
    best = (0.0, None)
    for t in STACK_SWEEP:
        keep = prob >= t
        if keep.any() and np.mean(d["on"][keep]) >= 0.9:
            c = score(prob, d, t)["completeness_0p2"]
            best = max(best, (c, float(t)), key=lambda b: b[0])
    return best


def stack(as_json: bool) -> None:
    """--stack: train the second stage by the filter's protocol and score it beside the first stage and the default
    cloud on the demo, --fresh and --fresh2 passes (nothing of those trained or chosen on)."""
    import time

    names = list(TRAIN_ALL)
    data = {}
    for name, spec in {**TRAIN_ALL, **HELD_OUT, **FRESH, **FRESH2}.items():
        print(f"  carving {name}", file=sys.stderr, flush=True)
        data[name] = run_pass(*spec, rivals=True)
    train, ys = [data[n] for n in names], [data[n]["on"] for n in names]
    x1 = [d["x"][:, COLS] for d in train]
    oof1 = []                                    # each training pass by the first stage trained without it
    for i, name in enumerate(names):
        print(f"  first stage without {name}", file=sys.stderr, flush=True)
        oof1.append(fit_x(x1[:i] + x1[i + 1:], ys[:i] + ys[i + 1:]).predict_proba(x1[i])[:, 1])
    first = fit_x(x1, ys)
    t1 = choose_threshold(train, oof1)
    stages = {"second": stack_x, "rivals": stack_x_rivals}     # the second stage; the same with the arc rivals
    models, thresholds, oof = {}, {"first": t1}, {"first": oof1}
    for k, make_x in stages.items():
        x2 = [make_x(d, q) for d, q in zip(train, oof1)]    # the second stage learns from out-of-fold probabilities
        oof[k] = []
        for i, name in enumerate(names):
            print(f"  {k}: second stage without {name}", file=sys.stderr, flush=True)
            oof[k].append(fit_x(x2[:i] + x2[i + 1:], ys[:i] + ys[i + 1:]).predict_proba(x2[i])[:, 1])
        models[k], thresholds[k] = fit_x(x2, ys), choose_threshold(train, oof[k])
    keys = ["first", *stages]
    out = {"thresholds": thresholds, "features_second": list(STACK_FEATURES),
           "features_rivals": list(STACK_FEATURES + RIVAL_NAMES), "training_left_out": {}, "sets": {}}
    for i, n in enumerate(names):
        out["training_left_out"][n] = {k: score(oof[k][i], train[i], thresholds[k]) for k in keys}
    print(f"thresholds (the filter's rule, on the training passes each left out): {thresholds}")
    for k in keys:
        r = [v[k] for v in out["training_left_out"].values()]
        print(f"  training passes left out, {k}: median {100 * np.median([m['acc_frac_0p2'] for m in r]):.1f} % "
              f"within 0.2 m, completeness {100 * np.median([m['completeness_0p2'] for m in r]):.1f} %")
    print(f"{'pass':>20} " + " ".join(f"{k:>11}" for k in ["default", *keys]) + "   at >= 90 %: "
          + " ".join(f"{k:>11}" for k in keys))
    timing = {k: [] for k in stages}
    for set_name, passes in (("demo", HELD_OUT), ("fresh", FRESH), ("fresh2", FRESH2)):
        res = out["sets"][set_name] = {}
        for n in passes:
            d = data[n]
            p = {"first": first.predict_proba(d["x"][:, COLS])[:, 1]}
            for k, make_x in stages.items():
                t = time.perf_counter()
                p[k] = models[k].predict_proba(make_x(d, p["first"]))[:, 1]
                timing[k].append((time.perf_counter() - t) * 1e3)
            r = res[n] = {"default": cloud_metrics(d["points"][d["default"]], d["surface"], d["visible"]),
                          **{k: score(p[k], d, thresholds[k]) for k in keys},
                          **{k + "_at_acc90": completeness_at_acc90(d, p[k]) for k in keys}}
            print(f"{n:>20} " + " ".join(f"{100 * r[k]['acc_frac_0p2']:5.1f}/{100 * r[k]['completeness_0p2']:5.1f}"
                                         for k in ["default", *keys])
                  + "   " + " ".join(f"{100 * r[k + '_at_acc90'][0]:5.1f}@{r[k + '_at_acc90'][1]}" for k in keys))
    out["ms_per_cloud_median"] = {k: float(np.median(v)) for k, v in timing.items()}
    print(f"second stages (context, rivals + scikit-learn's trees): median ms per cloud over the "
          f"{len(timing['second'])} passes {out['ms_per_cloud_median']} (a cloud every 10th ping: a tenth per ping)")
    for set_name, res in out["sets"].items():
        worse = {k: [n for n, r in res.items() if r[k]["acc_frac_0p2"] < r["default"]["acc_frac_0p2"] - WORSE_BY]
                 for k in keys}
        out["sets"][set_name] = {"passes": res, "below_default_by_2": worse}
        print(f"{set_name}: more than 2 points less accurate than the default: {worse}")
    if as_json:
        print(json.dumps(out))



def oracle_threshold(d: dict, prob: np.ndarray) -> tuple[float | None, dict | None]:
    """The lowest threshold (0.3-0.99 by 0.005) at which the pass keeps points no less accurate than its default
    cloud less WORSE_BY -- the threshold rule's criterion met exactly, chosen with the pass's own ground truth: the
    ceiling of any per-pass threshold under that criterion, not a rule -- and its metrics."""
    for t in np.round(np.arange(0.3, 0.99, 0.005), 3):
        keep = prob >= t
        if keep.any() and np.mean(d["on"][keep]) >= d["default_acc"] - WORSE_BY:
            return float(t), score(prob, d, t)
    return None, None


def calibrated(as_json: bool) -> None:
    """--calibrated: the filter trained by its protocol, scored on the demo, --fresh and --fresh2 passes with one
    global threshold and with a threshold per pass (carving_filter.keep_calibrated: isotonic calibration on the
    training passes' out-of-fold probabilities, the target precision chosen on them by choose_target), beside the
    default cloud from the same pings; the calibration checked per pass (reliability)."""
    import time

    names = list(TRAIN_ALL)
    data = {}
    for name, spec in {**TRAIN_ALL, **HELD_OUT, **FRESH, **FRESH2}.items():
        print(f"  carving {name}", file=sys.stderr, flush=True)
        data[name] = run_pass(*spec)
    train = [data[n] for n in names]
    oof = []
    for i, name in enumerate(names):
        print(f"  leaving out {name}", file=sys.stderr, flush=True)
        oof.append(probability(fit(train[:i] + train[i + 1:]), train[i]))
    threshold = choose_threshold(train, oof)
    target, maps = choose_target(train, oof)
    clf, cal = fit(train), carving_filter.calibration_map(fit_calibration(train, oof))
    out = {"calibrated_target_precision": target, "calibrated_global_threshold_p": threshold,
           "calibrated_map": {"p": cal[0].tolist(), "on_frac": cal[1].tolist()}, "calibrated_training_left_out": {},
           "calibrated_sets": {}}

    def both(d: dict, q: np.ndarray, m: tuple[np.ndarray, np.ndarray]) -> dict:
        kept = carving_filter.keep_calibrated(q, m, target_precision=target)
        qc = carving_filter.calibrate(q, m)
        return {"global": score(q, d, threshold),
                "calibrated": {**cloud_metrics(d["points"][kept.keep], d["surface"], d["visible"]),
                               "threshold_p": kept.threshold_p, "expected_precision": kept.expected_precision,
                               "note": kept.note},
                "reliability": reliability(d["on"], qc, q >= threshold)}

    print(f"global threshold {threshold}, target precision {target} (both: lowest at which <= {MAY_LOSE:.0%} of the "
          f"training passes, each left out, lose > {100 * WORSE_BY:.0f} points of accuracy against the default)")
    print(f"{'training pass left out':>22} {'default':>7} {'global':>11} {'calibrated':>11} {'its p':>6}   "
          f"predicted/observed on surface: all voted, kept at the global threshold")
    for i, n in enumerate(names):
        r = out["calibrated_training_left_out"][n] = {"default_acc": train[i]["default_acc"],
                                                      **both(train[i], oof[i], maps[i])}
        g, c, rel = r["global"], r["calibrated"], r["reliability"]
        print(f"{n:>22} {100 * r['default_acc']:7.1f} {100 * g['acc_frac_0p2']:5.1f}/{100 * g['completeness_0p2']:5.1f}"
              f" {100 * c['acc_frac_0p2']:5.1f}/{100 * c['completeness_0p2']:5.1f} {c['threshold_p'] or 0:6.3f}   "
              f"{rel['all'][0]:.3f}/{rel['all'][1]:.3f}  {rel['at_global_threshold'][0] or 0:.3f}/"
              f"{rel['at_global_threshold'][1] or 0:.3f}")
    lo = out["calibrated_training_left_out"].values()
    at_g = np.array([[r["reliability"]["at_global_threshold"][0], r["reliability"]["at_global_threshold"][1]]
                     for r in lo if r["reliability"]["at_global_threshold"][2]])
    out["calibrated_reliability_left_out"] = {
        "predicted_at_global_threshold_range": [float(at_g[:, 0].min()), float(at_g[:, 0].max())],
        "observed_at_global_threshold_range": [float(at_g[:, 1].min()), float(at_g[:, 1].max())],
        "corr_predicted_observed": float(np.corrcoef(at_g[:, 0], at_g[:, 1])[0, 1]),
        "median_global": [float(np.median([r["global"][k] for r in lo])) for k in ("acc_frac_0p2", "completeness_0p2")],
        "median_calibrated": [float(np.median([r["calibrated"][k] for r in lo]))
                              for k in ("acc_frac_0p2", "completeness_0p2")]}
    rl = out["calibrated_reliability_left_out"]
    print(f"reliability, training passes left out, kept at the global threshold: predicted on-surface share "
          f"{rl['predicted_at_global_threshold_range']}, observed {rl['observed_at_global_threshold_range']}, "
          f"correlation across passes {rl['corr_predicted_observed']:.2f}; medians (within 0.2 m, completeness): "
          f"global {rl['median_global']}, calibrated {rl['median_calibrated']}")
    print(f"{'pass':>20} {'default':>11} {'global':>11} {'calibrated':>11} {'its p':>6} {'pred/obs':>11} "
          f"{'ms rule':>7}   best at >= 90 % swept on the pass itself; default - 2 points, on itself")
    timing = []
    for set_name, passes in (("demo", HELD_OUT), ("fresh", FRESH), ("fresh2", FRESH2)):
        res = {}
        for n in passes:
            d = data[n]
            q = probability(clf, d)
            t = [time.perf_counter()]
            for _ in range(5):
                carving_filter.keep_calibrated(q, cal, target_precision=target)
                t.append(time.perf_counter())
            timing.append(1e3 * float(np.median(np.diff(t))))
            r = res[n] = {"default": cloud_metrics(d["points"][d["default"]], d["surface"], d["visible"]),
                          **both(d, q, cal), "global_at_acc90": completeness_at_acc90(d, q), "ms_rule": timing[-1]}
            r["oracle_threshold_p"], r["oracle"] = oracle_threshold(d, q)
            c, o = r["calibrated"], r["oracle"] or {"acc_frac_0p2": 0.0, "completeness_0p2": 0.0}
            print(f"{n:>20} " + " ".join(f"{100 * r[k]['acc_frac_0p2']:5.1f}/{100 * r[k]['completeness_0p2']:5.1f}"
                                         for k in ("default", "global", "calibrated"))
                  + f" {c['threshold_p'] or 0:6.3f} {c['expected_precision'] or 0:5.3f}/{c['acc_frac_0p2']:5.3f} "
                  f"{timing[-1]:7.2f}   {100 * r['global_at_acc90'][0]:5.1f}@{r['global_at_acc90'][1]}   "
                  f"{100 * o['acc_frac_0p2']:5.1f}/{100 * o['completeness_0p2']:5.1f}@{r['oracle_threshold_p']}")
        worse = {k: [n for n, r in res.items() if r[k]["acc_frac_0p2"] < r["default"]["acc_frac_0p2"] - WORSE_BY]
                 for k in ("global", "calibrated")}
        more = [n for n, r in res.items() if r["calibrated"]["completeness_0p2"] > r["global"]["completeness_0p2"]]
        out["calibrated_sets"][set_name] = {"passes": res, "below_default_by_2": worse,
                                            "completeness_up_vs_global": more}
        print(f"{set_name}: more than 2 points less accurate than the default: {worse}; calibrated more complete "
              f"than global on {len(more)} of {len(res)}")
    out["calibrated_ms_per_cloud_median"] = float(np.median(timing))
    demo = out["calibrated_sets"]["demo"]["passes"]["tripod_demo"]["calibrated"]
    out.update(calibrated_acc_frac_0p2=demo["acc_frac_0p2"], calibrated_completeness_0p2=demo["completeness_0p2"])
    print(f"the per-pass rule (calibrate, sort, cumulative mean): median {out['calibrated_ms_per_cloud_median']:.2f} "
          f"ms per cloud over the {len(timing)} passes")
    if as_json:
        print(json.dumps(out))

def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="write nodes/sonar/carving_filter.json")
    parser.add_argument("--json", action="store_true")
    parser.add_argument("--fresh", action="store_true", help="score the shipped model on never-seen passes (FRESH)")
    parser.add_argument("--fresh2", action="store_true", help="... on the second never-seen set (FRESH2)")
    parser.add_argument("--demo", action="store_true", help="... on the demo pass (held out of training)")
    parser.add_argument("--old-model", help="another model JSON scored beside the shipped one (--fresh*, --demo)")
    parser.add_argument("--stack", action="store_true", help="train and score the second stage (not shipped)")
    parser.add_argument("--calibrated", action="store_true",
                        help="train, calibrate and score a threshold per pass from calibrated probabilities")
    args = parser.parse_args()
    if args.stack:
        return stack(args.json)
    if args.calibrated:
        return calibrated(args.json)
    if args.fresh or args.fresh2 or args.demo:
        sets = {k: v for k, v, on in (("demo", HELD_OUT, args.demo), ("fresh", FRESH, args.fresh),
                                      ("fresh2", FRESH2, args.fresh2)) if on}
        return fresh(sets, args.old_model, args.json)
    data = {}
    for name, spec in {**TRAIN_ALL, **HELD_OUT}.items():
        print(f"  carving {name}", file=sys.stderr, flush=True)
        data[name] = run_pass(*spec)
    train = [data[n] for n in TRAIN_ALL]
    held_out = []                          # each training pass scored by the same recipe without it
    for i, name in enumerate(TRAIN_ALL):
        print(f"  leaving out {name}", file=sys.stderr, flush=True)
        held_out.append(probability(fit(train[:i] + train[i + 1:]), train[i]))
    threshold = choose_threshold(train, held_out)
    target, _ = choose_target(train, held_out)
    clf = fit(train)
    if args.write:
        carving_filter.export_model(clf, carving_filter.MODEL_PATH, threshold_p=threshold, trained_on=list(TRAIN_ALL),
                                    max_depth=3, features=MODEL_FEATURES,
                                    threshold_rule=f"lowest at which at most {MAY_LOSE:.0%} of the training passes, "
                                    f"each left out of training, lose more than {100 * WORSE_BY:.0f} points of "
                                    "accuracy (within 0.2 m) against the default cloud",
                                    calibration=fit_calibration(train, held_out), target_precision=target,
                                    calibration_rule="isotonic, on the training passes' out-of-fold probabilities "
                                    "(each pass alike); target_precision: the threshold_rule's criterion over the "
                                    "passes each left out of training and calibration (keep_rule='calibrated')")
        exported = carving_filter.surface_probability(data["tripod_demo"]["x"], carving_filter.load_model.__wrapped__())
        assert np.allclose(exported, probability(clf, data["tripod_demo"]), atol=1e-9)
    result = {"threshold_p": threshold, "target_precision": target, "features": list(MODEL_FEATURES),
              "trained_on": list(TRAIN_ALL),
              "held_out": list(HELD_OUT), "passes": {}}
    print(f"threshold {threshold} (lowest at which <= {MAY_LOSE:.0%} of the training passes, each left out, lose "
          f"> {100 * WORSE_BY:.0f} points of accuracy against the default cloud)")
    print(f"{'pass':>20} {'role':>9} {'points':>7} {'<=0.2 m %':>9} {'complete %':>10}   left out: "
          f"{'<=0.2 m %':>9} {'complete %':>10}   default: {'<=0.2 m %':>9}")
    loo = dict(zip(TRAIN_ALL, held_out))
    for name, d in data.items():
        m = score(probability(clf, d), d, threshold)
        row = dict(role="held out" if name in HELD_OUT else "trained", default_acc=d["default_acc"], **m)
        if name in loo:
            row["loo"] = score(loo[name], d, threshold)
        result["passes"][name] = row
        loo_txt = (f"{100 * row['loo']['acc_frac_0p2']:9.1f} {100 * row['loo']['completeness_0p2']:10.1f}"
                   if "loo" in row else f"{'':9} {'':10}")
        print(f"{name:>20} {row['role']:>9} {m['points']:7d} {100 * m['acc_frac_0p2']:9.1f} "
              f"{100 * m['completeness_0p2']:10.1f}             {loo_txt}            {100 * d['default_acc']:9.1f}")
    if args.json:
        print(json.dumps(result))


if __name__ == "__main__":
    main()
