#!/usr/bin/env bash
# Runs schemathesis with its default checks against `gateway demo`: every operation of the
# served OpenAPI document, with generated valid and invalid requests; any finding fails.
#
#   bash .ci/schemathesis.sh [GATEWAY_BINARY]     # default: target/debug/gateway
#
# Installs schemathesis into .venv (the tests' Python environment) when it is missing. The demo
# listens on loopback ports the kernel picks (port 0); it is stopped on exit. Operations whose
# answers depend on rules a JSON schema cannot state are listed in .ci/schemathesis.toml.
set -euo pipefail
cd "$(dirname "$0")/.."

BIN="${1:-target/debug/gateway}"
ST_VERSION=4.32.5

if ! .venv/bin/python -c "import importlib.metadata as m; assert m.version('schemathesis') == '$ST_VERSION'" 2>/dev/null; then
  [ -x .venv/bin/python ] || python3 -m venv .venv
  .venv/bin/pip install -q "schemathesis==$ST_VERSION"
fi

TMP="$(mktemp -d)"
"$BIN" demo --modbus-tcp 127.0.0.1:0 --http 127.0.0.1:0 --zenoh-listen tcp/127.0.0.1:0 \
  >"$TMP/out" 2>"$TMP/err" &
demo=$!
trap 'kill "$demo" 2>/dev/null; wait "$demo" 2>/dev/null; rm -rf "$TMP"' EXIT

http=""
for _ in $(seq 1 100); do
  http="$(sed -n 's/^http listening on //p' "$TMP/out")"
  [ -n "$http" ] && break
  kill -0 "$demo" 2>/dev/null || { cat "$TMP/err" >&2; echo "schemathesis: the demo stopped" >&2; exit 1; }
  sleep 0.1
done
[ -n "$http" ] || { echo "schemathesis: the demo did not listen for HTTP" >&2; exit 1; }

.venv/bin/st --config-file .ci/schemathesis.toml run "http://$http/api/v1/openapi.json" --workers 2
