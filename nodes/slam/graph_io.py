"""Read and write SE(2) pose graphs: g2o (``VERTEX_SE2`` / ``EDGE_SE2``) and TORO (``VERTEX2`` / ``EDGE2``).

The two formats differ where it hurts (see ../shared/specs/pose-graphs.md):

* g2o ``EDGE_SE2 i j dx dy dth q11 q12 q13 q22 q23 q33`` -- the information's upper
  triangle, row by row, in the frame of the measurement.
* TORO ``EDGE2 i j dx dy dth I11 I12 I22 I33 I13 I23`` -- the same six numbers with the
  angle's entry fourth. Reading one as the other gives a wrong problem without an error,
  so the format is decided by the tags in the file, and asking for the other one is an
  error, not a guess.

A file with edges but no vertices (some published g2o files) is accepted: the missing
poses are initialised from the edges by the optimiser. ``FIX id`` lines hold vertices.
Every malformed line is a :class:`GraphError` naming the file and line.
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from nodes.slam.pose_graph import GraphError, PoseGraph2D

FORMATS = ("g2o", "toro")
_TAGS = {"g2o": ("VERTEX_SE2", "EDGE_SE2"), "toro": ("VERTEX2", "EDGE2")}
_IGNORED = {"VERTEX_XY", "EDGE_SE2_XY", "PARAMS_SE2OFFSET", "EDGE_SE2_PRIOR"}   # landmarks etc.: not SE(2) poses


def _info_g2o(v: list[float]) -> np.ndarray:
    q11, q12, q13, q22, q23, q33 = v
    return np.array([[q11, q12, q13], [q12, q22, q23], [q13, q23, q33]])


def _info_toro(v: list[float]) -> np.ndarray:
    i11, i12, i22, i33, i13, i23 = v
    return np.array([[i11, i12, i13], [i12, i22, i23], [i13, i23, i33]])


def _id(text: str) -> int:
    """A vertex id: an integer that fits the graph's int64 ids."""
    value = int(text)
    if not -(1 << 63) <= value < 1 << 63:
        raise ValueError(f"vertex id {text} does not fit 64 bits")
    return value


def detect_format(path: str | Path) -> str:
    """'g2o' or 'toro', from the tags in the file (not its name)."""
    if Path(path).exists() and not Path(path).is_file():       # a directory, /dev/zero: no lines to read
        raise GraphError(f"{path}: not a regular file (give a .g2o or TORO .graph file)")
    found = set()
    with open(path, encoding="utf-8", errors="replace") as fh:
        for line in fh:
            tag = line.split(maxsplit=1)[0] if line.strip() else ""
            for fmt, tags in _TAGS.items():
                if tag in tags:
                    found.add(fmt)
            if len(found) > 1:
                break
    if len(found) != 1:
        raise GraphError(f"{path}: " + ("holds both g2o and TORO records" if found
                                        else "no VERTEX_SE2/EDGE_SE2 (g2o) or VERTEX2/EDGE2 (TORO) records"))
    return found.pop()


def read_graph(path: str | Path, *, fmt: str | None = None) -> PoseGraph2D:
    """Read a g2o or TORO SE(2) graph; ``fmt`` (default: detected) must match the file's tags."""
    path = Path(path)
    found = detect_format(path)
    if fmt is not None and fmt != found:
        raise GraphError(f"{path}: asked to read it as {fmt}, but it holds {found} records "
                         f"({' / '.join(_TAGS[found])}); its information matrix is ordered differently, "
                         f"so reading it as {fmt} would silently give a wrong problem")
    vertex_tag, edge_tag = _TAGS[found]
    parse_info = _info_g2o if found == "g2o" else _info_toro
    vertices: dict[int, tuple[float, float, float]] = {}
    edges: list[tuple[int, int, tuple[float, float, float], np.ndarray]] = []
    fixed: list[int] = []
    with open(path, encoding="utf-8", errors="replace") as fh:
        for number, line in enumerate(fh, start=1):
            parts = line.split()
            if not parts or parts[0].startswith("#"):
                continue
            tag, fields = parts[0], parts[1:]
            where = f"{path}:{number}"
            try:
                if tag == vertex_tag:
                    if len(fields) != 4:
                        raise ValueError(f"{tag} has id x y theta (4 fields), got {len(fields)}")
                    vid = _id(fields[0])
                    if vid in vertices:
                        raise ValueError(f"vertex {vid} is defined twice")
                    vertices[vid] = tuple(_finite(fields[1:4]))  # type: ignore[assignment]
                elif tag == edge_tag:
                    if len(fields) != 11:
                        raise ValueError(f"{tag} has i j dx dy dtheta and 6 information entries (11 fields), "
                                         f"got {len(fields)}")
                    values = _finite(fields[2:])
                    edges.append((_id(fields[0]), _id(fields[1]), tuple(values[:3]), parse_info(values[3:])))  # type: ignore[arg-type]
                elif tag == "FIX":
                    fixed += [_id(f) for f in fields]
                elif tag in _IGNORED or tag.startswith(("VERTEX", "EDGE")):
                    raise ValueError(f"{tag} records are not SE(2) poses; this reader takes "
                                     f"{vertex_tag} / {edge_tag} only")
            except ValueError as exc:
                raise GraphError(f"{where}: {exc}") from None
    if not edges and not vertices:
        raise GraphError(f"{path}: no vertices and no edges")
    graph = PoseGraph2D.from_edges(edges, vertices)
    missing = [f for f in fixed if f not in set(graph.ids.tolist())]
    if missing:
        raise GraphError(f"{path}: FIX names vertices that do not exist: {missing[:5]}")
    graph.fixed = {graph.index_of(f) for f in fixed}
    return graph


def _finite(fields: list[str]) -> list[float]:
    values = [float(f) for f in fields]
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"non-finite value in {' '.join(fields)}")
    return values


def write_graph(path: str | Path, graph: PoseGraph2D, poses: np.ndarray | None = None, *,
                fmt: str | None = None) -> None:
    """Write ``graph`` (with ``poses``, default its own) as g2o or TORO (default: from the suffix, .graph = TORO)."""
    path = Path(path)
    fmt = fmt or ("toro" if path.suffix == ".graph" else "g2o")
    if fmt not in FORMATS:
        raise ValueError(f"format is one of {FORMATS}")
    poses = graph.poses if poses is None else poses
    vertex_tag, edge_tag = _TAGS[fmt]
    lines = [f"{vertex_tag} {vid} {x:.9g} {y:.9g} {t:.9g}" for vid, (x, y, t) in zip(graph.ids.tolist(), poses.tolist())]
    ids = graph.ids
    for (i, j), z, om in zip(graph.edges.tolist(), graph.z.tolist(), graph.info):
        if fmt == "g2o":
            info = (om[0, 0], om[0, 1], om[0, 2], om[1, 1], om[1, 2], om[2, 2])
        else:
            info = (om[0, 0], om[0, 1], om[1, 1], om[2, 2], om[0, 2], om[1, 2])
        lines.append(f"{edge_tag} {ids[i]} {ids[j]} " + " ".join(f"{v:.9g}" for v in (*z, *info)))
    if graph.fixed and fmt == "g2o":
        lines.append("FIX " + " ".join(str(ids[k]) for k in sorted(graph.fixed)))
    path.write_text("\n".join(lines) + "\n")
