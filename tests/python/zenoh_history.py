#!/usr/bin/env python3
"""A late subscriber of the gateway, written with the Python binding (PyPI eclipse-zenoh).

Used by tests/tests/zenoh.rs. It connects to one explicit endpoint with multicast scouting off,
then, in order:

1. gets <prefix>/<key> until the gateway answers with at least one tag (the first polls are
   done) and prints {"kind": "get", "keys": [...]};
2. waits --settle seconds, so that values which never change (the KS vario's) were published
   long before anyone subscribes;
3. declares an advanced subscriber with history (zenoh.ext.declare_advanced_subscriber with
   HistoryConfig) on <prefix>/<key>, collects what it receives for --window seconds, and prints
   {"kind": "history", "keys": [...], "first_after": seconds, "samples": [...], "plain": [...]}
   (a sample's "live": it carries a timestamp, as publications do and history replies do not;
   "plain": what a plain subscriber declared at the same moment received meanwhile);
4. prints {"kind": "done"} and exits 0. Any wait longer than --timeout prints
   {"kind": "error", ...} and exits 1.

Every line on stdout is one JSON object.
"""

import argparse
import json
import queue
import sys
import time

import zenoh
import zenoh.ext


def emit(obj):
    print(json.dumps(obj), flush=True)


def fail(message):
    emit({"kind": "error", "message": message})
    sys.exit(1)


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--endpoint", required=True)
    p.add_argument("--prefix", required=True)
    p.add_argument("--key", required=True)
    p.add_argument("--settle", type=float, default=3.0)
    p.add_argument("--window", type=float, default=3.0)
    p.add_argument("--timeout", type=float, default=30.0)
    args = p.parse_args()
    key = f"{args.prefix}/{args.key}"

    conf = zenoh.Config()
    conf.insert_json5("mode", '"client"')
    conf.insert_json5("connect/endpoints", json.dumps([args.endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)

    deadline = time.monotonic() + args.timeout
    keys = []
    while not keys:
        keys = sorted(str(r.ok.key_expr) for r in session.get(key) if r.ok is not None)
        if not keys:
            if time.monotonic() > deadline:
                fail(f"no tag under {key} within {args.timeout} s")
            time.sleep(0.5)
    emit({"kind": "get", "keys": keys})

    time.sleep(args.settle)

    received = queue.Queue()
    plain = queue.Queue()
    start = time.monotonic()
    plain_sub = session.declare_subscriber(
        key, lambda s: plain.put((time.monotonic() - start, str(s.key_expr)))
    )
    sub = zenoh.ext.declare_advanced_subscriber(
        session,
        key,
        lambda s: received.put((time.monotonic() - start, s)),
        history=zenoh.ext.HistoryConfig(max_samples=1),
    )
    samples = []
    end = start + args.window
    while True:
        left = end - time.monotonic()
        if left <= 0:
            break
        try:
            at, s = received.get(timeout=left)
        except queue.Empty:
            break
        samples.append(
            {
                "at": at,
                "key": str(s.key_expr),
                "payload": json.loads(s.payload.to_bytes()),
                # A live publication carries the session's timestamp, a history reply none.
                "live": s.timestamp is not None,
            }
        )
    sub.undeclare()
    plain_sub.undeclare()
    plain_samples = []
    while not plain.empty():
        plain_samples.append(plain.get())
    emit(
        {
            "kind": "history",
            "keys": sorted({s["key"] for s in samples}),
            "first_after": min((s["at"] for s in samples), default=None),
            "samples": samples,
            "plain": [{"at": at, "key": k} for at, k in plain_samples],
        }
    )
    session.close()
    emit({"kind": "done"})


if __name__ == "__main__":
    main()
