"""A link model between nodes or machines: message loss, a bandwidth cap and scheduled outages.

Declared in a launch file, so a scenario's network is part of the pipeline, not of the
algorithm under test::

    links:
      - between: [robot0, robot1]     # node ids or machine names; both directions
        drop: 0.05                     # probability a message is lost
        bandwidth_bps: 200000          # token bucket: a message that finds too few tokens is lost
        burst_bytes: 65536             # the bucket's depth (default: one second of bandwidth)
        outages_s: [[10, 20]]          # [start, end) in seconds since the launcher started
        seed: 1

The model acts where a message is received, before it is decoded: a lost message is
counted on that input (``dropped_link`` in ``_stats``), and the publisher's ``seq`` gap
shows it too. The cap polices (drops) rather than shapes (delays): a radio's queue is
short, and what an application must survive is loss.
"""
from __future__ import annotations

import math
import random
from dataclasses import dataclass, field
from typing import Any

from tether.errors import ConfigError

LINK_KEYS = {"between", "drop", "bandwidth_bps", "burst_bytes", "outages_s", "seed"}


@dataclass
class LinkModel:
    """What happens to messages crossing one link. ``epoch_ns`` is when the schedule's clock started."""

    drop: float = 0.0
    bandwidth_bps: float = 0.0          # 0: no cap
    burst_bytes: float = 0.0            # 0: one second of bandwidth
    outages_s: list[tuple[float, float]] = field(default_factory=list)
    seed: int = 0
    epoch_ns: int = 0

    def __post_init__(self) -> None:
        self._rng = random.Random(self.seed)
        self._tokens = self.depth
        self._last_ns: int | None = None

    @property
    def depth(self) -> float:
        return self.burst_bytes or self.bandwidth_bps / 8.0

    def admit(self, nbytes: int, now_ns: int) -> str:
        """'' when the message gets through, else why it is lost ('outage', 'drop', 'bandwidth')."""
        t = (now_ns - self.epoch_ns) / 1e9
        if any(start <= t < end for start, end in self.outages_s):
            return "outage"
        if self.drop and self._rng.random() < self.drop:
            return "drop"
        if self.bandwidth_bps:
            if self._last_ns is not None:
                self._tokens = min(self.depth, self._tokens + (now_ns - self._last_ns) / 1e9 * self.bandwidth_bps / 8.0)
            self._last_ns = now_ns
            if nbytes > self._tokens:
                return "bandwidth"
            self._tokens -= nbytes
        return ""

    def to_json(self) -> dict[str, Any]:
        return {"drop": self.drop, "bandwidth_bps": self.bandwidth_bps, "burst_bytes": self.burst_bytes,
                "outages_s": [list(o) for o in self.outages_s], "seed": self.seed, "epoch_ns": self.epoch_ns}

    @classmethod
    def from_json(cls, spec: dict[str, Any]) -> "LinkModel":
        return cls(drop=float(spec.get("drop", 0.0)), bandwidth_bps=float(spec.get("bandwidth_bps", 0.0)),
                   burst_bytes=float(spec.get("burst_bytes", 0.0)),
                   outages_s=[(float(a), float(b)) for a, b in spec.get("outages_s", [])],
                   seed=int(spec.get("seed", 0)), epoch_ns=int(spec.get("epoch_ns", 0)))


def parse_link(where: str, raw: Any, names: set[str]) -> tuple[frozenset[str], LinkModel]:
    """One ``links:`` entry: the two ends (node ids or machine names) and its model; a
    :class:`ConfigError` naming the key otherwise."""
    if not isinstance(raw, dict):
        raise ConfigError(f"{where}: a link is a mapping with 'between' and the model's keys")
    unknown = set(raw) - LINK_KEYS
    if unknown:
        raise ConfigError(f"{where}: unknown link key {sorted(unknown)[0]!r} (known: {', '.join(sorted(LINK_KEYS))})")
    ends = raw.get("between")
    if not isinstance(ends, list) or len(ends) != 2 or not all(isinstance(e, str) for e in ends) or ends[0] == ends[1]:
        raise ConfigError(f"{where}: 'between' is two different node ids or machine names")
    for e in ends:
        if e not in names:
            raise ConfigError(f"{where}: link end {e!r} is neither a node id nor a machine")

    def number(key: str, lo: float, hi: float) -> float:
        v = raw.get(key, 0.0)
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
            raise ConfigError(f"{where}: link {key} must be a number in [{lo:g}, {hi:g}], got {v!r}")
        return float(v)

    outages = raw.get("outages_s", [])
    if not isinstance(outages, list) or not all(
            isinstance(o, list) and len(o) == 2 and all(isinstance(x, (int, float)) and not isinstance(x, bool)
                                                        and math.isfinite(x) for x in o) and 0 <= o[0] < o[1]
            for o in outages):
        raise ConfigError(f"{where}: outages_s is a list of [start, end] seconds with 0 <= start < end")
    seed = raw.get("seed", 0)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ConfigError(f"{where}: link seed must be an integer")
    model = LinkModel(drop=number("drop", 0.0, 1.0), bandwidth_bps=number("bandwidth_bps", 0.0, 1e12),
                      burst_bytes=number("burst_bytes", 0.0, 1e12),
                      outages_s=[(float(a), float(b)) for a, b in outages], seed=seed)
    return frozenset(ends), model
