"""bench/readme.py: README rows come from the benches' JSON, rows without a formatter stay and are named."""
from __future__ import annotations

import json
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "bench"))

import readme  # noqa: E402

PING = {"parse_beams_per_s": 30000.0, "parse_beams_per_s_brping": 2000.0, "parse_ratio": 15.0, "parse_agree": True,
        "line": [{"baud": 115200, "beams_per_s": 9.3, "line_limit_beams_per_s": 9.4, "latency_ms_p50": 0.2,
                  "latency_ms_p99": 0.5, "checksum_errors": 0},
                 {"baud": 2000000, "beams_per_s": 150.0, "line_limit_beams_per_s": 163.0, "latency_ms_p50": 0.3,
                  "latency_ms_p99": 0.7, "checksum_errors": 0}]}


def test_rows_come_from_json_and_hand_rows_are_named(tmp_path, monkeypatch):
    monkeypatch.setattr(readme, "OUT", tmp_path)
    (tmp_path / "ping360.json").write_text(json.dumps(PING))
    lines = [readme.HEADER, "|---|---|---|---|",
             "| `ping360.py` old | typed 1 | typed 2 | typed 3 |",
             "| `transport.py` 64 B | 194 us | raw | met |", "", "after"]
    new, hand = readme.rows(lines)
    assert len(new) == 2 and "30,000 beams/s" in new[0] and "typed 1" not in new[0]
    assert new[1] == lines[3] and hand == ["transport"]


def test_every_readme_row_names_its_bench():
    lines = (REPO / "README.md").read_text().split("\n")
    start, end = readme._table_span(lines)
    names = [readme._bench_of(r) for r in lines[start:end]]
    assert all(names) and all((REPO / "bench" / f"{n}.py").exists() for n in names)


def test_every_readme_row_has_a_formatter():
    lines = (REPO / "README.md").read_text().split("\n")
    start, end = readme._table_span(lines)
    missing = {readme._bench_of(r) for r in lines[start:end]} - set(readme.FORMATTERS)
    assert not missing, f"rows typed by hand: {sorted(missing)}"


def test_last_json_skips_a_table_printed_before_it():
    text = 'ring 21 {not json}\n  more table\n{"a": 1, "b": {"c": 2}}\n'
    assert readme.last_json(text) == {"a": 1, "b": {"c": 2}}
