#!/usr/bin/env python3
"""A zenoh client of the gateway, written with the Python binding (PyPI eclipse-zenoh).

Used by gateway/tests/zenoh_bridge.rs. It connects to one explicit endpoint with multicast
scouting off, then, in order:

1. subscribes to <prefix>/** and prints {"kind": "ready"};
2. waits for a tag value on <prefix>/drive/atv/speed and a telegram on <prefix>/r3964/rx and
   prints each as {"kind": "sample", ...} (the first of each key only);
3. gets <prefix>/drive/*/* and prints {"kind": "get", ...} per reply, then "get_done";
4. puts a telegram on <prefix>/r3964/tx (attachment "py-1") and prints the result from
   <prefix>/r3964/tx/result as {"kind": "tx_result", ...};
5. puts 42 on <prefix>/drive/atv/cmd/set and prints the result as {"kind": "set_result", ...};
6. asks for the liveliness tokens under <prefix>/** and prints {"kind": "tokens", ...};
7. prints {"kind": "done"} and exits 0. Any wait longer than --timeout prints
   {"kind": "error", ...} and exits 1.

Every line on stdout is one JSON object.
"""

import argparse
import json
import queue
import sys
import time

import zenoh


def emit(obj):
    print(json.dumps(obj), flush=True)


def fail(message):
    emit({"kind": "error", "message": message})
    sys.exit(1)


def sample_to_json(sample):
    payload = sample.payload.to_bytes()
    out = {
        "key": str(sample.key_expr),
        "encoding": str(sample.encoding),
        "payload_hex": payload.hex(),
    }
    try:
        out["payload"] = json.loads(payload)
    except ValueError:
        pass
    if sample.attachment is not None:
        out["attachment"] = sample.attachment.to_bytes().decode("utf-8", "replace")
    return out


def wait_for(samples, key, timeout):
    """The next sample on exactly `key`, skipping others."""
    deadline = time.monotonic() + timeout
    while True:
        left = deadline - time.monotonic()
        if left <= 0:
            fail(f"no sample on {key} within {timeout} s")
        try:
            sample = samples.get(timeout=left)
        except queue.Empty:
            continue
        if str(sample.key_expr) == key:
            return sample


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--endpoint", required=True, help="e.g. tcp/127.0.0.1:7447")
    parser.add_argument("--prefix", required=True, help="e.g. gw/demo")
    parser.add_argument("--mode", default="client", choices=["client", "peer"])
    parser.add_argument("--timeout", type=float, default=20.0)
    # The keys below the prefix (defaults: the bridge test's backend; the demo passes its own).
    parser.add_argument("--tag-key", default="drive/atv/speed")
    parser.add_argument("--get-key", default="drive/*/*")
    parser.add_argument("--set-key", default="drive/atv/cmd")
    parser.add_argument("--set-value", default="42")
    parser.add_argument("--tx-line", default="r3964")
    args = parser.parse_args()
    prefix = args.prefix

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(args.mode))
    conf.insert_json5("connect/endpoints", json.dumps([args.endpoint]))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)

    samples = queue.Queue()
    subscriber = session.declare_subscriber(f"{prefix}/**", samples.put)
    emit({"kind": "ready", "zenoh": "eclipse-zenoh"})

    # 2. Publications from the gateway.
    wanted = {f"{prefix}/{args.tag_key}", f"{prefix}/{args.tx_line}/rx"}
    seen = set()
    deadline = time.monotonic() + args.timeout
    while seen != wanted:
        left = deadline - time.monotonic()
        if left <= 0:
            fail(f"saw only {sorted(seen)} of {sorted(wanted)}")
        try:
            sample = samples.get(timeout=left)
        except queue.Empty:
            continue
        key = str(sample.key_expr)
        if key in wanted and key not in seen:
            seen.add(key)
            emit({"kind": "sample", **sample_to_json(sample)})

    # 3. Tag values by query, with wildcards.
    count = 0
    for reply in session.get(f"{prefix}/{args.get_key}", timeout=args.timeout):
        if reply.ok is None:
            fail(f"error reply: {reply.err.payload.to_string()}")
        emit({"kind": "get", **sample_to_json(reply.ok)})
        count += 1
    emit({"kind": "get_done", "count": count})

    # 4. A telegram to send.
    session.put(f"{prefix}/{args.tx_line}/tx", b"\x02PY\x03", attachment=b"py-1")
    result = wait_for(samples, f"{prefix}/{args.tx_line}/tx/result", args.timeout)
    emit({"kind": "tx_result", **sample_to_json(result)})

    # 5. A value to write.
    session.put(f"{prefix}/{args.set_key}/set", args.set_value)
    result = wait_for(samples, f"{prefix}/{args.set_key}/set/result", args.timeout)
    emit({"kind": "set_result", **sample_to_json(result)})

    # 6. Presence.
    tokens = sorted(
        str(reply.ok.key_expr)
        for reply in session.liveliness().get(f"{prefix}/**", timeout=args.timeout)
        if reply.ok is not None
    )
    emit({"kind": "tokens", "keys": tokens})

    subscriber.undeclare()
    session.close()
    emit({"kind": "done"})


if __name__ == "__main__":
    main()
