#!/usr/bin/env python3
"""A zenoh router made with the Python binding (PyPI eclipse-zenoh), for tests/tests/fleet.rs.

It listens on tcp/127.0.0.1:<port> only, multicast scouting off, prints one line
`router <zenoh id> listening on tcp/127.0.0.1:<port>` once open, and routes until it is killed
or its stdin closes. With `--config FILE` instead of a port it opens the zenoh config file FILE
(JSON5, e.g. deploy/zenoh/router.json5 with mutual TLS and access control) as it is.
"""

import json
import sys

import zenoh


def main() -> int:
    if sys.argv[1] == "--config":
        conf = zenoh.Config.from_file(sys.argv[2])
        endpoint = conf.get_json("listen/endpoints")
    else:
        port = int(sys.argv[1])
        endpoint = f"tcp/127.0.0.1:{port}"
        conf = zenoh.Config()
        conf.insert_json5("mode", '"router"')
        conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
        conf.insert_json5("connect/endpoints", "[]")
        conf.insert_json5("scouting/multicast/enabled", "false")
    try:
        session = zenoh.open(conf)
    except Exception as e:  # the port taken: the test picks another
        print(f"router not open: {e}", flush=True)
        return 1
    print(f"router {session.info.zid()} listening on {endpoint}", flush=True)
    sys.stdin.read()
    session.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
