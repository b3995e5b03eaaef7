#!/usr/bin/env bash
# Checks the deployment files with the real tools available on this machine.
#
#   bash deploy/check.sh           # from anywhere; exits non-zero if any check fails
#   bash deploy/check.sh --image   # also builds the FROM scratch image with buildah (needs the
#                                  # musl binary: see deploy/README.md)
#
# Required: promtool (Debian package `prometheus`) and python3. Optional, skipped with a message
# when missing: systemd-analyze, python3 yaml (`python3-yaml`), yamllint, hadolint, buildah.
# No container engine runs here, so `docker compose config` is replaced by parsing the compose
# file and checking what it refers to.
set -uo pipefail

DEPLOY="$(cd "$(dirname "$0")" && pwd)"
ROOT="$(dirname "$DEPLOY")"
TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT

passed=0
failed=0
skipped=0
build_image=0
[ "${1:-}" = "--image" ] && build_image=1

pass() { passed=$((passed + 1)); echo "ok    $1"; }
fail() { failed=$((failed + 1)); echo "FAIL  $1"; }
skip() { skipped=$((skipped + 1)); echo "skip  $1"; }

# run NAME CMD...: a check passes when CMD exits 0; its output is shown when it fails.
run() {
  local name="$1"
  shift
  if "$@" >"$TMP/out" 2>&1; then
    pass "$name"
  else
    fail "$name"
    sed 's/^/      /' "$TMP/out"
  fi
}

have() { command -v "$1" >/dev/null 2>&1; }

python_has_yaml() { python3 -c 'import yaml' >/dev/null 2>&1; }

# --- Prometheus ------------------------------------------------------------------------------
if have promtool; then
  run "promtool check config deploy/prometheus.yml" promtool check config "$DEPLOY/prometheus.yml"
  run "promtool check rules deploy/alerts.yml" promtool check rules "$DEPLOY/alerts.yml"
  run "promtool test rules deploy/alerts.test.yml" promtool test rules "$DEPLOY/alerts.test.yml"
  sed 's/__TARGET__/127.0.0.1:8080/' "$DEPLOY/prometheus-test.yml" >"$TMP/prometheus-test.yml"
  run "promtool check config deploy/prometheus-test.yml (target filled in)" \
    promtool check config "$TMP/prometheus-test.yml"
else
  fail "promtool missing: apt-get install prometheus (it ships promtool)"
fi

# --- systemd unit ----------------------------------------------------------------------------
verify_unit() {
  # The binary is not installed here: verify a copy whose ExecStart is /bin/true, everything
  # else as written. Any message about the unit (unknown key, bad value) fails the check.
  mkdir -p "$TMP/unit"
  sed 's|/usr/local/bin/gateway|/bin/true|g' "$DEPLOY/gateway.service" >"$TMP/unit/gateway.service"
  local out
  out="$(systemd-analyze verify "$TMP/unit/gateway.service" 2>&1)" || { echo "$out"; return 1; }
  if printf '%s\n' "$out" | grep -q 'gateway.service'; then
    echo "$out"
    return 1
  fi
}
unit_security() {
  # Exposure of the hardening, 0 best .. 10 (the threshold counts tenths): 1.8 when written;
  # fail above 3.0.
  systemd-analyze security --offline=true --threshold=30 "$TMP/unit/gateway.service" >"$TMP/security" 2>&1 \
    || { tail -3 "$TMP/security"; return 1; }
  tail -1 "$TMP/security"
}
if have systemd-analyze; then
  run "systemd-analyze verify deploy/gateway.service" verify_unit
  if systemd-analyze security --help 2>/dev/null | grep -q -- '--offline'; then
    run "systemd-analyze security --offline deploy/gateway.service (exposure <= 3)" unit_security
  else
    skip "systemd-analyze security --offline (needs systemd 252 or later)"
  fi
  unit_grace() {
    # TimeoutStopSec must lie above the gateway's 10 s grace period.
    local t
    t="$(sed -n 's/^TimeoutStopSec=\([0-9]*\)s$/\1/p' "$DEPLOY/gateway.service")"
    [ -n "$t" ] && [ "$t" -gt 10 ] || { echo "TimeoutStopSec=${t:-?}s is not above 10 s"; return 1; }
  }
  run "gateway.service stop timeout above the 10 s grace period" unit_grace
  unit_config_writable() {
    # The REST API saves the configuration next to itself: the --config file's directory must be
    # writable for the service under ProtectSystem=strict.
    local cfg dir
    cfg="$(sed -n 's/^ExecStart=.* --config \([^ ]*\).*$/\1/p' "$DEPLOY/gateway.service")"
    dir="$(dirname "$cfg")"
    grep -qx "ReadWritePaths=$dir" "$DEPLOY/gateway.service" \
      || { echo "ExecStart's config $cfg: no ReadWritePaths=$dir"; return 1; }
  }
  run "gateway.service may save its configuration (ReadWritePaths)" unit_config_writable
  unit_devices_and_exit_codes() {
    # The usual serial device classes are allowed, and a configuration error (exit 64) is not
    # restarted.
    local class
    for class in ttyS ttyUSB ttyACM ttyAMA; do
      grep -qx "DeviceAllow=char-$class rw" "$DEPLOY/gateway.service" \
        || { echo "no DeviceAllow=char-$class rw"; return 1; }
    done
    grep -qx "RestartPreventExitStatus=64" "$DEPLOY/gateway.service" \
      || { echo "no RestartPreventExitStatus=64"; return 1; }
  }
  run "gateway.service allows ttyS/ttyUSB/ttyACM/ttyAMA, does not restart on exit 64" \
    unit_devices_and_exit_codes
else
  skip "systemd-analyze not installed: deploy/gateway.service not verified"
fi

# --- compose file (no engine here: parse it and check what it refers to) ----------------------
check_compose() {
  python3 - "$DEPLOY/compose.yaml" "$ROOT" <<'PY'
import os, re, sys, yaml

path, root = sys.argv[1], sys.argv[2]
base = os.path.dirname(path)
doc = yaml.safe_load(open(path))
problems = []
services = doc.get("services", {})
for name in ("gateway", "prometheus", "grafana", "zenoh", "cab1", "cab2"):
    if name not in services:
        problems.append(f"service {name} missing")
if not str(services.get("zenoh", {}).get("image", "")).startswith("eclipse/zenoh"):
    problems.append("zenoh service is not the eclipse/zenoh image")
gateway = services.get("gateway", {})
if not gateway.get("devices"):
    problems.append("gateway passes no serial device in")
grace = str(gateway.get("stop_grace_period", ""))
m = re.fullmatch(r"(\d+)s", grace)
if not m or int(m.group(1)) <= 10:
    problems.append(f"gateway stop_grace_period {grace!r} not above the 10 s grace period")
build = gateway.get("build", {})
dockerfile = os.path.join(base, build.get("context", "."), build.get("dockerfile", "Dockerfile"))
if not os.path.isfile(dockerfile):
    problems.append(f"build dockerfile {dockerfile} missing")
# The gateway's configuration directory is mounted whole and writable, so that the REST API can
# save a change (rename(2) over a single bind-mounted file fails with EBUSY).
config_mounts = [v for v in gateway.get("volumes", []) if v.split(":")[1:2] == ["/etc/gateway"]]
if len(config_mounts) != 1 or config_mounts[0].endswith(":ro"):
    problems.append(f"gateway: /etc/gateway must be one writable directory mount, not {config_mounts}")
# Bind mounts: every relative source must exist, except the operator's own configuration directory.
for sname, svc in services.items():
    for vol in svc.get("volumes", []):
        src = vol.split(":")[0]
        if src.startswith("."):
            full = os.path.normpath(os.path.join(base, src))
            if os.path.basename(full) in ("gateway.toml", "etc-gateway"):
                continue
            if not os.path.exists(full):
                problems.append(f"{sname}: bind mount source {src} does not exist")
        elif src not in doc.get("volumes", {}):
            problems.append(f"{sname}: named volume {src} not declared")
# The router is connected to the gateway's zenoh peer.
zenoh_cmd = [str(a) for a in services.get("zenoh", {}).get("command", [])]
connects = [zenoh_cmd[i + 1] for i, a in enumerate(zenoh_cmd[:-1]) if a in ("--connect", "-e")]
if not any(c.startswith("tcp/gateway:") for c in connects):
    problems.append(f"zenoh router does not connect to the gateway (connect: {connects})")
# The fleet: two demo gateways under distinct names, the router connected to each, Prometheus
# scraping each, and no service waiting for one of an optional profile.
names = []
for demo in ("cab1", "cab2"):
    cmd = [str(a) for a in services.get(demo, {}).get("command", [])]
    if not cmd or cmd[0] != "demo" or "--name" not in cmd:
        problems.append(f"{demo}: not a named demo gateway ({cmd})")
        continue
    names.append(cmd[cmd.index("--name") + 1])
    if not any(c.startswith(f"tcp/{demo}:") for c in connects):
        problems.append(f"zenoh router does not connect to {demo} (connect: {connects})")
    g = str(services.get(demo, {}).get("stop_grace_period", ""))
    m = re.fullmatch(r"(\d+)s", g)
    if not m or int(m.group(1)) <= 10:
        problems.append(f"{demo} stop_grace_period {g!r} not above the 10 s grace period")
if len(set(names)) != len(names):
    problems.append(f"the demo gateways share a name: {names} (the second would be refused)")
prom = open(os.path.join(base, "prometheus.yml")).read()
for demo in ("cab1", "cab2"):
    if f"{demo}:8080" not in prom:
        problems.append(f"prometheus.yml does not scrape {demo}:8080")
for sname, svc in services.items():
    for dep in svc.get("depends_on", []):
        if services.get(dep, {}).get("profiles") and not svc.get("profiles"):
            problems.append(f"{sname} depends on {dep}, which runs only with a profile")
# Grafana's admin password comes from a secret, never admin/admin.
grafana = services.get("grafana", {})
env = grafana.get("environment", {})
if env.get("GF_SECURITY_ADMIN_PASSWORD__FILE") != "/run/secrets/grafana-admin-password" \
        or "grafana-admin-password" not in grafana.get("secrets", []) \
        or "grafana-admin-password" not in doc.get("secrets", {}) \
        or "GF_SECURITY_ADMIN_PASSWORD" in env:
    problems.append("grafana: the admin password must come from the grafana-admin-password secret")
for p in problems:
    print(p)
sys.exit(1 if problems else 0)
PY
}
if python_has_yaml; then
  run "compose.yaml parses; services, mounts, grace period, zenoh router, Grafana secret" check_compose
else
  skip "python3 yaml missing (apt-get install python3-yaml): deploy/compose.yaml not checked"
fi

# --- Grafana dashboards and provisioning ------------------------------------------------------
check_dashboards() {
  python3 - "$ROOT/dashboards" <<'PY'
import glob, json, os, sys
problems = []
uids = {}
for path in sorted(glob.glob(os.path.join(sys.argv[1], "*.json"))):
    d = json.load(open(path))
    for key in ("uid", "title", "panels", "schemaVersion"):
        if key not in d:
            problems.append(f"{path}: no {key}")
    if d.get("uid") in uids:
        problems.append(f"{path}: uid {d['uid']} also in {uids[d['uid']]}")
    uids[d.get("uid")] = path
    ids = [p.get("id") for p in d.get("panels", [])]
    if len(ids) != len(set(ids)):
        problems.append(f"{path}: duplicate panel ids")
if not uids:
    problems.append("no dashboards")
for p in problems:
    print(p)
sys.exit(1 if problems else 0)
PY
}
run "dashboards/*.json parse; uids and panel ids unique" check_dashboards
check_provisioning() {
  python3 - "$ROOT/dashboards/provisioning" <<'PY'
import sys, yaml
base = sys.argv[1]
dash = yaml.safe_load(open(f"{base}/dashboards/gateway.yaml"))
ds = yaml.safe_load(open(f"{base}/datasources/prometheus.yaml"))
assert dash["apiVersion"] == 1 and dash["providers"][0]["type"] == "file", dash
assert ds["apiVersion"] == 1 and ds["datasources"][0]["type"] == "prometheus", ds
PY
}
if python_has_yaml; then
  run "dashboards/provisioning YAML parses" check_provisioning
else
  skip "python3 yaml missing: provisioning files not checked"
fi
if have yamllint; then
  run "yamllint (line length 120)" yamllint -d '{extends: relaxed, rules: {line-length: {max: 120}}}' \
    "$DEPLOY/prometheus.yml" "$DEPLOY/prometheus-test.yml" "$DEPLOY/alerts.yml" \
    "$DEPLOY/alerts.test.yml" "$DEPLOY/compose.yaml" \
    "$ROOT/dashboards/provisioning/dashboards/gateway.yaml" \
    "$ROOT/dashboards/provisioning/datasources/prometheus.yaml"
else
  skip "yamllint not installed"
fi

# --- Dockerfile --------------------------------------------------------------------------------
runtime_stages_match() {
  # deploy/Containerfile.scratch is deploy/Dockerfile's runtime stage for a host-built binary.
  diff <(sed -n '/^FROM scratch/,$p' "$DEPLOY/Dockerfile" | grep -v '^COPY') \
    <(sed -n '/^FROM scratch/,$p' "$DEPLOY/Containerfile.scratch" | grep -v '^COPY')
}
run "Dockerfile and Containerfile.scratch runtime stages match" runtime_stages_match
dockerfile_rules() {
  local f="$DEPLOY/Dockerfile" ok=0
  grep -q '^FROM scratch' "$f" || { echo "runtime stage is not FROM scratch"; ok=1; }
  # Multi-arch: the builder maps TARGETARCH to both musl targets and builds for the one chosen.
  grep -q 'x86_64-unknown-linux-musl' "$f" || { echo "no x86_64 musl build"; ok=1; }
  grep -q 'aarch64-unknown-linux-musl' "$f" || { echo "no arm64 musl build"; ok=1; }
  grep -q '^ARG TARGETARCH' "$f" || { echo "the builder does not take TARGETARCH"; ok=1; }
  grep -q -- '--release --target "$target"' "$f" || { echo "no release build for the target"; ok=1; }
  grep -Eq '^USER [0-9]+:[0-9]+$' "$f" || { echo "no numeric non-root USER"; ok=1; }
  grep -Eq '^USER 0(:|$)' "$f" && { echo "runs as root"; ok=1; }
  return $ok
}
run "Dockerfile: x86_64 and arm64 musl builds, FROM scratch, numeric non-root user" dockerfile_rules
if have hadolint; then
  run "hadolint deploy/Dockerfile" hadolint "$DEPLOY/Dockerfile"
  run "hadolint deploy/Containerfile.scratch" hadolint "$DEPLOY/Containerfile.scratch"
else
  skip "hadolint not installed (not packaged in Debian): Dockerfiles not linted"
fi

# --- the example's device templates travel with it ---------------------------------------------
example_with_templates() {
  # The example names template_dirs = ["templates"], taken from its own directory: wherever a
  # recipe or a check installs gateway.example.toml as a configuration, it installs deploy/templates
  # beside it, or `gateway check` of the installed example fails ("no template ...").
  local ok=0 f
  grep -q '^template_dirs = \["templates"\]' "$DEPLOY/gateway.example.toml" \
    || { echo "gateway.example.toml no longer names template_dirs = [\"templates\"]: update this check"; ok=1; }
  ls "$DEPLOY"/templates/*.toml >/dev/null 2>&1 || { echo "no templates in deploy/templates"; ok=1; }
  for f in README.md compose.yaml Dockerfile Containerfile.scratch image-check.sh arm64-check.sh; do
    if grep -Eq '(install|cp) .*gateway\.example\.toml|/etc/gateway|image-root/etc' "$DEPLOY/$f" \
      && ! grep -q 'templates' "$DEPLOY/$f"; then
      echo "deploy/$f installs the example configuration without deploy/templates"; ok=1
    fi
  done
  return $ok
}
run "the example configuration is installed with the device templates it names" example_with_templates

# --- udev rule ---------------------------------------------------------------------------------
check_udev() {
  # udevadm verify exists from systemd 254 on; use it when there, else a syntax check of our own.
  if udevadm verify --help >/dev/null 2>&1; then
    udevadm verify "$DEPLOY/99-gateway-serial.rules"
    return
  fi
  python3 - "$DEPLOY/99-gateway-serial.rules" <<'PY'
import re, sys
pair = re.compile(r'\s*([A-Z_]+(\{[^}]+\})?)\s*(==|!=|\+=|-=|:=|=)\s*"([^"]*)"\s*')
problems = []
for no, line in enumerate(open(sys.argv[1]), 1):
    line = line.strip()
    if not line or line.startswith("#"):
        continue
    rest, matches, assigns = line, 0, 0
    while rest:
        m = pair.match(rest)
        if not m:
            problems.append(f"line {no}: cannot parse {rest!r}")
            break
        matches += m.group(3) in ("==", "!=")
        assigns += m.group(3) not in ("==", "!=")
        rest = rest[m.end():]
        if rest.startswith(","):
            rest = rest[1:]
        elif rest:
            problems.append(f"line {no}: expected ',' before {rest!r}")
            break
    if not (matches and assigns):
        problems.append(f"line {no}: a rule needs a match and an assignment")
for p in problems:
    print(p)
sys.exit(1 if problems else 0)
PY
}
run "udev rule syntax deploy/99-gateway-serial.rules" check_udev

# --- the FROM scratch image (on request) --------------------------------------------------------
if [ "$build_image" = 1 ]; then
  build_scratch_image() {
    local bin="$ROOT/target/x86_64-unknown-linux-musl/release/gateway"
    [ -x "$bin" ] || { echo "build $bin first (deploy/README.md)"; return 1; }
    file "$bin" | grep -q 'statically linked\|static-pie linked' || { file "$bin"; return 1; }
    mkdir -p "$TMP/root/etc/gateway/templates" "$TMP/root/var/lib/gateway"
    install -m 0755 "$bin" "$TMP/root/gateway"
    install -m 0644 "$DEPLOY"/templates/*.toml "$TMP/root/etc/gateway/templates/"
    buildah bud -q -f "$DEPLOY/Containerfile.scratch" -t cp341-gateway-check "$TMP/root" \
      && buildah inspect --type image --format '{{.OCIv1.Config.User}}' cp341-gateway-check
  }
  if have buildah; then
    run "buildah bud deploy/Containerfile.scratch" build_scratch_image
  else
    skip "buildah not installed: image not built"
  fi
fi

echo "deploy-check: $passed passed, $failed failed, $skipped skipped"
[ "$failed" = 0 ]
