"""Checkpoints of Flax models as msgpack (never pickle): parameters, optimiser state and metadata,
refused with a clear error when they do not fit the model they are loaded into.

>>> save_checkpoint("out/learn/ae.msgpack", {"params": params, "opt_state": opt_state}, meta={"step": 1200})
>>> state, meta = load_checkpoint("out/learn/ae.msgpack", {"params": params, "opt_state": opt_state})
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import numpy as np
from flax import serialization

FORMAT = "tether.checkpoint/1"


def _shapes(tree: Any) -> dict[str, tuple[int, ...]]:
    flat = jax.tree_util.tree_flatten_with_path(tree)[0]
    return {jax.tree_util.keystr(path): tuple(np.shape(leaf)) for path, leaf in flat}


def save_checkpoint(path: str | Path, state: Any, *, meta: dict[str, Any] | None = None) -> int:
    """Write ``state`` (any pytree of arrays) and ``meta`` (msgpack-able values); returns bytes written."""
    doc = {"format": FORMAT, "state": serialization.to_state_dict(state), "meta": dict(meta or {})}
    data = serialization.msgpack_serialize(doc)
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_bytes(data)
    tmp.replace(path)                 # a crash mid-write leaves the previous checkpoint whole
    return len(data)


def load_checkpoint(path: str | Path, like: Any) -> tuple[Any, dict[str, Any]]:
    """Read a checkpoint into the structure of ``like``; ``ValueError`` naming the first array whose
    shape differs (or that is missing) when it was written for another model."""
    doc = serialization.msgpack_restore(Path(path).read_bytes())
    if not isinstance(doc, dict) or doc.get("format") != FORMAT:
        raise ValueError(f"{path}: not a tether checkpoint (format "
                         f"{doc.get('format') if isinstance(doc, dict) else type(doc).__name__!r})")
    target = serialization.to_state_dict(like)
    want, got = _shapes(target), _shapes(doc["state"])
    for key, shape in want.items():
        if key not in got:
            raise ValueError(f"{path}: no array {key} (the checkpoint is of another model)")
        if got[key] != shape:
            raise ValueError(f"{path}: {key} has shape {got[key]} in the checkpoint, the model has {shape}")
    extra = sorted(set(got) - set(want))
    if extra:
        raise ValueError(f"{path}: arrays the model does not have, e.g. {extra[0]} (the checkpoint is of another model)")
    return serialization.from_state_dict(like, doc["state"]), doc.get("meta") or {}
