#!/usr/bin/env python3
"""An independent Zenoh subscriber for the jetbench tests, on PyPI's
eclipse-zenoh: no jetbench code is involved.

  zenoh_subscriber.py --connect tcp/HOST:PORT --namespace NS --recording run.mcap --out got.json

Connects (peer mode, no scouting) to a bridge, prints "subscribed", and
collects every payload published under jetbench/NS/** until SIGTERM or
SIGINT. Then it decodes each payload as a CDR message with the schema that
the run's recording (written meanwhile) has for the topic /<channel>, using
the reference MCAP reader (mcap + mcap-ros2-support), and writes JSON:

  {"encodings": {topic: zenoh encoding}, "messages": {topic: [{field: value}]}, "errors": [...]}
"""
import argparse
import json
import math
import signal
import sys
import threading

import zenoh
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory


def plain(value):
    if isinstance(value, float) and not math.isfinite(value):
        return repr(value)
    if isinstance(value, (list, tuple)):
        return [plain(v) for v in value]
    return value


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--connect", required=True)
    parser.add_argument("--namespace", required=True)
    parser.add_argument("--recording", required=True)
    parser.add_argument("--out", required=True)
    args = parser.parse_args()

    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())

    config = zenoh.Config()
    config.insert_json5("mode", '"peer"')
    config.insert_json5("connect/endpoints", json.dumps([args.connect]))
    config.insert_json5("scouting/multicast/enabled", "false")
    config.insert_json5("scouting/gossip/enabled", "false")
    session = zenoh.open(config)
    prefix = f"jetbench/{args.namespace}/"
    received = []

    def on_sample(sample):
        received.append((str(sample.key_expr), str(sample.encoding), bytes(sample.payload.to_bytes())))

    subscriber = session.declare_subscriber(prefix + "**", on_sample)
    print("subscribed", flush=True)
    while not stop.wait(0.1):
        pass
    subscriber.undeclare()
    session.close()

    with open(args.recording, "rb") as f:
        summary = make_reader(f).get_summary()
    schemas = {c.topic: summary.schemas[c.schema_id] for c in summary.channels.values()}
    factory = DecoderFactory()
    decoders = {}
    encodings, messages, errors = {}, {}, []
    for key, encoding, payload in received:
        topic = "/" + key[len(prefix):]
        encodings.setdefault(topic, encoding)
        try:
            if topic not in decoders:
                decoders[topic] = factory.decoder_for("cdr", schemas[topic])
            decoded = decoders[topic](payload)
            messages.setdefault(topic, []).append({k: plain(getattr(decoded, k)) for k in decoded.__slots__})
        except Exception as e:  # a payload that does not decode is the finding
            if len(errors) < 20:
                errors.append(f"{topic}: {len(payload)} bytes: {e!r}")
    with open(args.out, "w") as f:
        json.dump({"encodings": encodings, "messages": messages, "errors": errors}, f)


if __name__ == "__main__":
    sys.exit(main())
