#!/usr/bin/env python3
"""A rogue zenoh peer (PyPI eclipse-zenoh), for tests/tests/fleet_rogue.rs.

It plays what any machine that reaches a plant's zenoh fabric can do without being a gateway:

    zenoh_rogue.py --connect ENDPOINT [--tls CA CERT KEY] [--tokens N] [--field-kb KB]
                   [--hold NAME] [--host TEXT] [--link URL] [--answer-all M]
    zenoh_rogue.py --connect ENDPOINT [--tls CA CERT KEY] --probe KEY

- `--tokens N`: declares N liveliness tokens `gw/rogue<i>` and answers `gw/rogue<i>/status`
  with every text field (name, host, http, zenoh.zid) of KB KiB;
- `--hold NAME`: also holds the token `gw/NAME` (another gateway's name) and answers its status
  with `--host` and `--link` (a forged host and a phishing link);
- a query on a wildcard (`gw/*/status`, as `gateway fleet status` asks) is answered for the
  first M of the tokens (`--answer-all`, default 50);
- `--probe KEY`: prints `live <count>` for a liveliness get on KEY and exits.

It is a client of ENDPOINT only (multicast scouting off); `--tls` gives it a CA and a client
certificate for `tls/` endpoints (mutual TLS). It prints `rogue ready <tokens>` once every token
is declared (or `rogue not connected: <error>` and exits 2) and runs until stdin closes.
"""

import argparse
import json
import sys

import zenoh


def config(args):
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("connect/endpoints", json.dumps([args.connect]))
    c.insert_json5("scouting/multicast/enabled", "false")
    # Give up at once when the endpoint refuses us (no retry loop in a test).
    c.insert_json5("connect/timeout_ms", "3000")
    c.insert_json5("connect/exit_on_failure", "true")
    if args.tls:
        ca, cert, key = args.tls
        c.insert_json5("transport/link/tls/root_ca_certificate", json.dumps(ca))
        c.insert_json5("transport/link/tls/connect_certificate", json.dumps(cert))
        c.insert_json5("transport/link/tls/connect_private_key", json.dumps(key))
        c.insert_json5("transport/link/tls/enable_mtls", "true")
    return c


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--connect", required=True)
    p.add_argument("--tls", nargs=3, metavar=("CA", "CERT", "KEY"))
    p.add_argument("--tokens", type=int, default=0)
    p.add_argument("--field-kb", type=int, default=0)
    p.add_argument("--hold")
    p.add_argument("--host", default="plant-host")
    p.add_argument("--link", default="http://evil.example/phish")
    p.add_argument("--answer-all", type=int, default=50)
    p.add_argument("--probe")
    args = p.parse_args()
    try:
        s = zenoh.open(config(args))
    except Exception as e:  # refused: no certificate, or a certificate of another CA
        print(f"rogue not connected: {e}", flush=True)
        return 2
    if args.probe:
        live = 0
        for r in s.liveliness().get(args.probe, timeout=2.0):
            if r.ok is not None:
                live += 1
        print(f"live {live}", flush=True)
        s.close()
        return 0

    fill = "A" * (args.field_kb * 1024)
    names = [f"rogue{i}" for i in range(args.tokens)]

    def body(name):
        if name == args.hold:
            return {"name": name, "host": args.host, "http": args.link, "pid": 1,
                    "zenoh": {"zid": "abcd", "listen": ["tcp/0.0.0.0:7447"]}}
        return {"name": name + fill, "host": fill, "http": "http://x/" + fill,
                "zenoh": {"zid": fill}, "pid": 1}

    def handler(q):
        k = str(q.key_expr)
        parts = k.split("/")
        if len(parts) == 3 and parts[1] != "*":
            targets = [parts[1]]
        else:  # a wildcard: answer for the first M
            targets = ([args.hold] if args.hold else []) + names[: args.answer_all]
        for name in targets:
            if name == args.hold or name in names:
                try:
                    q.reply(f"gw/{name}/status", json.dumps(body(name)))
                except Exception:
                    pass

    qs = s.declare_queryable("gw/*/status", handler)
    tokens = []
    if args.hold:
        tokens.append(s.liveliness().declare_token(f"gw/{args.hold}"))
    for name in names:
        tokens.append(s.liveliness().declare_token(f"gw/{name}"))
    print(f"rogue ready {len(tokens)}", flush=True)
    sys.stdin.read()
    for t in tokens:
        t.undeclare()
    qs.undeclare()
    s.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
