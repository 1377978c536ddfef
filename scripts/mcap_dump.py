#!/usr/bin/env python3
"""Decode every message of a jetbench MCAP file with the reference Python
reader (mcap + mcap-ros2-support) and print JSON:

  {"channels": {topic: {"schema": name, "schema_encoding": .., "message_encoding": ..}},
   "messages": {topic: [{field: value, ...}, ...]}}

No jetbench code is involved: this is the independent check that recordings
decode with standard tools. Usage: mcap_dump.py FILE.mcap
"""
import json
import math
import sys

from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def plain(value):
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)  # JSON has no NaN/inf; keep it visible
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    return value


def main(path):
    channels, messages = {}, {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for schema, channel, _message, decoded in reader.iter_decoded_messages():
            channels.setdefault(channel.topic, {
                "schema": schema.name,
                "schema_encoding": schema.encoding,
                "message_encoding": channel.message_encoding,
            })
            fields = decoded.__slots__
            messages.setdefault(channel.topic, []).append({k: plain(getattr(decoded, k)) for k in fields})
    json.dump({"channels": channels, "messages": messages}, sys.stdout)


if __name__ == "__main__":
    if len(sys.argv) != 2:
        sys.exit("usage: mcap_dump.py FILE.mcap")
    main(sys.argv[1])
