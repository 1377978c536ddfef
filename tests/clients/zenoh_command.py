#!/usr/bin/env python3
"""An independent control-room client for the jetbench tests, on PyPI's
eclipse-zenoh: sends commands to a bench's Zenoh gateway and prints the answers.

  zenoh_command.py --connect tls/HOST:PORT [--ca ca.crt --cert me.crt --key me.key] \
      KEY[=VALUE] ...

Each KEY (e.g. jetbench/NS/op/alice/cmd/start, jetbench/NS/cmd/stop) is queried
once, in order, with VALUE as the payload if given, and one JSON line is printed
per query: {"key": KEY, "replies": ["accepted" | "refused: ..." | ...]} (an empty
list when nothing answered within --timeout seconds: the bench's access control
drops queries a session may not send). If the session cannot be opened (a TLS
handshake the bench refuses), one line {"connect_error": "..."} and exit code 3.

With --heartbeat SECONDS, the client does what an operator's tool does while it
holds control: from a `.../cmd/take` or `.../cmd/handover` answered `accepted`
(taken, offered or accepted) until a `.../cmd/release`
answered `accepted`, it sends `.../cmd/heartbeat` every SECONDS on a thread of its
own (their answers are not printed). With --insist SECONDS, a `take` that is refused is sent
again every 0.5 s for up to SECONDS (an operator waiting for the holder's link
to lapse); only its last answer is printed. A query `sleep=SECONDS` waits that long
(heartbeats going on), and prints {"slept": SECONDS}.
"""
import argparse
import json
import sys
import threading
import time

import zenoh


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--connect", required=True)
    parser.add_argument("--ca")
    parser.add_argument("--cert")
    parser.add_argument("--key")
    parser.add_argument("--timeout", type=float, default=3.0)
    parser.add_argument("--heartbeat", type=float, default=0.0)
    parser.add_argument("--insist", type=float, default=0.0)
    parser.add_argument("queries", nargs="+")
    args = parser.parse_args()

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("connect/endpoints", json.dumps([args.connect]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("connect/timeout_ms", "5000")
    conf.insert_json5("connect/exit_on_failure", "true")
    if args.ca:
        conf.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(args.ca))
    if args.cert:
        conf.insert_json5("transport/link/tls/connect_certificate", json.dumps(args.cert))
        conf.insert_json5("transport/link/tls/connect_private_key", json.dumps(args.key))
        conf.insert_json5("transport/link/tls/enable_mtls", "true")
    try:
        session = zenoh.open(conf)
    except Exception as e:  # the handshake refused, nothing listening
        print(json.dumps({"connect_error": str(e)}), flush=True)
        return 3
    beating = None  # (key, stop event) while control is held

    def beat(key, stop):
        while not stop.wait(args.heartbeat):
            try:
                for _ in session.get(key, timeout=args.heartbeat):
                    pass
            except Exception:  # the session closing under us
                return

    try:
        for query in args.queries:
            key, _, value = query.partition("=")
            if key == "sleep":
                time.sleep(float(value))
                print(json.dumps({"slept": float(value)}), flush=True)
                continue
            deadline = time.monotonic() + (args.insist if key.endswith("/cmd/take") else 0.0)
            while True:
                replies = []
                get = session.get(key, payload=value if value else None, timeout=args.timeout)
                for reply in get:
                    if reply.ok is not None:
                        replies.append(reply.ok.payload.to_string())
                    else:
                        replies.append("error: " + reply.err.payload.to_string())
                if replies == ["accepted"] or time.monotonic() >= deadline:
                    break
                time.sleep(0.5)
            print(json.dumps({"key": key, "replies": replies}), flush=True)
            held = replies == ["accepted"]
            taken = key.endswith("/cmd/take") or key.endswith("/cmd/handover")
            if args.heartbeat > 0 and held and taken and beating is None:
                stop = threading.Event()
                beat_key = key.rsplit("/", 1)[0] + "/heartbeat"
                threading.Thread(target=beat, args=(beat_key, stop), daemon=True).start()
                beating = stop
            if held and key.endswith("/cmd/release") and beating is not None:
                beating.set()
                beating = None
    finally:
        if beating is not None:
            beating.set()
        session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
