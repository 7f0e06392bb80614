"""Export a tether log for other tools: Foxglove reads MCAP with json channels and jsonschema schemas."""
from __future__ import annotations

import base64
import json
from pathlib import Path
from typing import Any

from mcap.writer import Writer

from tether.log import LogReader


def _jsonable(value: Any) -> Any:
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_jsonable(v) for v in value]
    if isinstance(value, (bytes, bytearray, memoryview)):
        return base64.b64encode(bytes(value)).decode()
    if isinstance(value, float) and value != value:
        return None      # NaN is not JSON
    return value


def export_foxglove(src: str | Path, dst: str | Path) -> int:
    """Rewrite ``src`` with json-encoded channels (arrays' ``data`` base64, as their schema says)."""
    reader = LogReader(src)
    schemas_by_type = reader.schemas()     # the original schemas travel along
    count = 0
    with open(dst, "wb") as fh:
        writer = Writer(fh)
        writer.start(profile="", library="tether export")
        schema_ids: dict[str, int] = {}
        channel_ids: dict[str, int] = {}
        for rec in reader.messages():
            if rec.type_name not in schema_ids:
                data = schemas_by_type.get(rec.type_name, b"{}")
                schema_ids[rec.type_name] = writer.register_schema(rec.type_name, "jsonschema", data)
            if rec.topic not in channel_ids:
                channel_ids[rec.topic] = writer.register_channel(rec.topic, "json", schema_ids[rec.type_name])
            doc = _jsonable(LogReader.decode_plain(rec))
            writer.add_message(channel_ids[rec.topic], log_time=rec.log_time_ns, publish_time=rec.publish_time_ns,
                               data=json.dumps(doc, allow_nan=False).encode())
            count += 1
        writer.finish()
    return count
