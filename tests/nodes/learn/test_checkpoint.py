"""msgpack checkpoints: round trip, and a model of another shape refused by name."""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from nodes.learn.checkpoint import load_checkpoint, save_checkpoint


def test_round_trip_and_mismatch(tmp_path):
    state = {"dense": {"kernel": jnp.arange(6.0).reshape(2, 3), "bias": jnp.zeros(3)}}
    save_checkpoint(tmp_path / "c.msgpack", state, meta={"step": 7})
    back, meta = load_checkpoint(tmp_path / "c.msgpack", state)
    assert meta == {"step": 7} and np.array_equal(back["dense"]["kernel"], state["dense"]["kernel"])
    other = {"dense": {"kernel": jnp.zeros((4, 3)), "bias": jnp.zeros(3)}}
    with pytest.raises(ValueError, match=r"kernel'\] has shape \(2, 3\) in the checkpoint, the model has \(4, 3\)"):
        load_checkpoint(tmp_path / "c.msgpack", other)
    with pytest.raises(ValueError, match="no array"):
        load_checkpoint(tmp_path / "c.msgpack", {**state, "head": {"w": jnp.zeros(2)}})
    (tmp_path / "x").write_bytes(b"\x81\xa1a\x01")
    with pytest.raises(ValueError, match="not a tether checkpoint"):
        load_checkpoint(tmp_path / "x", state)
