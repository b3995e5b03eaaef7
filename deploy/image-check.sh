#!/usr/bin/env bash
# Builds the FROM scratch image of the gateway without any image registry and runs the binary
# inside it:
#
#   bash deploy/image-check.sh          # from anywhere; exits non-zero on the first failure
#   bash deploy/image-check.sh --keep   # also keeps the image, tagged localhost/cp341-gateway
#
# Steps: install what is missing (apt: buildah; rustup: the x86_64-unknown-linux-musl target;
# apt: musl-tools, for ring's C code), build the static musl release
# binary, check that it has no interpreter and no shared libraries, build
# deploy/Containerfile.scratch with buildah (deploy/gateway.example.toml as
# /etc/gateway/gateway.toml), then inside a container of that image, as the image's user:
# `/gateway --version` prints the workspace version, `/gateway check` of the example config
# prints `ok: ...` and exits 0, a broken config exits 1.
# Removes the containers and the image it created (by their names) when it ends.
#
# Containers run with `buildah run --isolation chroot`: no runtime (crun, runc) or ulimit flags
# needed. CARGO_TARGET_DIR is honoured (default: target/ of the repository).
set -euo pipefail

DEPLOY="$(cd "$(dirname "$0")" && pwd)"
ROOT="$(dirname "$DEPLOY")"
TARGET=x86_64-unknown-linux-musl
TARGET_DIR="${CARGO_TARGET_DIR:-$ROOT/target}"
BIN="$TARGET_DIR/$TARGET/release/gateway"
# Names unique to this run, so that only what this run created is removed.
IMAGE="localhost/cp341-gateway-image-check:$$"
CONTAINER="cp341-gateway-image-check-$$"
KEEP_AS="localhost/cp341-gateway"
keep=0
[ "${1:-}" = "--keep" ] && keep=1

TMP="$(mktemp -d)"
image_built=0
container_made=0
cleanup() {
  local rc=$?
  if [ "$container_made" = 1 ]; then
    buildah rm "$CONTAINER" >/dev/null 2>&1 \
      || echo "image-check: could not remove container $CONTAINER" >&2
  fi
  if [ "$image_built" = 1 ]; then
    # With --keep the image stays under its second tag; rmi of this tag only untags it then.
    buildah rmi "$IMAGE" >/dev/null 2>&1 || echo "image-check: could not remove image $IMAGE" >&2
  fi
  rm -rf "$TMP"
  exit "$rc"
}
trap cleanup EXIT

die() {
  echo "image-check: FAIL: $*" >&2
  exit 1
}
step() { echo "image-check: $*"; }
have() { command -v "$1" >/dev/null 2>&1; }

SUDO=""
if [ "$(id -u)" != 0 ] && have sudo; then SUDO="sudo"; fi
apt_install() {
  step "apt-get install $*"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "$@"
}

# --- tools -----------------------------------------------------------------------------------
have buildah || apt_install buildah
have readelf || apt_install binutils
if ! rustup target list --installed | grep -qx "$TARGET"; then
  step "rustup target add $TARGET"
  rustup target add "$TARGET"
fi

# --- the static binary -----------------------------------------------------------------------
build() {
  (cd "$ROOT" && CARGO_TARGET_DIR="$TARGET_DIR" \
    cargo build --locked --release --target "$TARGET" -p gateway --bin gateway)
}
# ring (the TLS provider of Modbus/TCP Security) compiles C against the libc headers: the musl
# build needs musl-gcc.
have musl-gcc || apt_install musl-tools
step "cargo build --locked --release --target $TARGET -p gateway --bin gateway"
t0=$SECONDS
build || die "musl release build failed"
build_seconds=$((SECONDS - t0))
[ -x "$BIN" ] || die "$BIN missing after the build"

static_check() {
  # Static: no program interpreter (PT_INTERP) and no shared library (DT_NEEDED).
  if readelf -lW "$BIN" | grep -q 'INTERP'; then
    readelf -lW "$BIN" | grep -A1 INTERP >&2
    return 1
  fi
  if readelf -dW "$BIN" | grep -q '(NEEDED)'; then
    readelf -dW "$BIN" | grep '(NEEDED)' >&2
    return 1
  fi
}
static_check || die "$BIN is not statically linked"
bin_bytes="$(stat -c %s "$BIN")"
step "static binary: $BIN ($bin_bytes bytes, built in ${build_seconds}s)"

# --- the image -------------------------------------------------------------------------------
# The build context holds the binary, the example config with the templates it names and the state
# directory; the Containerfile copies etc/gateway as it is, so the example becomes
# /etc/gateway/gateway.toml and its template directory ("templates") /etc/gateway/templates.
ctx="$TMP/root"
mkdir -p "$ctx/etc/gateway" "$ctx/var/lib/gateway"
install -m 0755 "$BIN" "$ctx/gateway"
install -m 0644 "$DEPLOY/gateway.example.toml" "$ctx/etc/gateway/gateway.toml"
install -d -m 0755 "$ctx/etc/gateway/templates"
install -m 0644 "$DEPLOY"/templates/*.toml "$ctx/etc/gateway/templates/"
step "buildah bud -f deploy/Containerfile.scratch -t $IMAGE"
t0=$SECONDS
buildah bud -q -f "$DEPLOY/Containerfile.scratch" -t "$IMAGE" "$ctx" >/dev/null \
  || die "buildah bud deploy/Containerfile.scratch failed"
image_built=1
bud_seconds=$((SECONDS - t0))

user="$(buildah inspect --type image --format '{{.OCIv1.Config.User}}' "$IMAGE")"
[ "$user" = "10001:10001" ] || die "image user is '$user', expected 10001:10001"
image_size="$(buildah images --format '{{.Size}}' "$IMAGE" | head -1)"

# --- inside the image ------------------------------------------------------------------------
buildah from -q --name "$CONTAINER" "$IMAGE" >/dev/null || die "buildah from $IMAGE failed"
container_made=1
in_image() { buildah run --isolation chroot "$CONTAINER" -- "$@"; }

version="$(sed -n 's/^version = "\(.*\)"$/\1/p' "$ROOT/Cargo.toml" | head -1)"
[ -n "$version" ] || die "no version in Cargo.toml"
out="$(in_image /gateway --version)" || die "/gateway --version failed in the image: $out"
step "in the image: /gateway --version -> $out"
[ "$out" = "gateway $version" ] \
  || die "/gateway --version printed '$out', expected 'gateway $version'"

rc=0
out="$(in_image /gateway check --config /etc/gateway/gateway.toml)" || rc=$?
step "in the image: /gateway check --config /etc/gateway/gateway.toml -> exit $rc: $out"
[ "$rc" = 0 ] || die "gateway check of the example config exited $rc"
case "$out" in ok:*) ;; *) die "gateway check did not print 'ok: ...'" ;; esac

# A broken copy of the example (a parity that does not exist), copied into this container only.
grep -q '^parity = "even"$' "$DEPLOY/gateway.example.toml" \
  || die "deploy/gateway.example.toml has no 'parity = \"even\"' line to break"
sed 's/^parity = "even"$/parity = "sometimes"/' "$DEPLOY/gateway.example.toml" >"$TMP/broken.toml"
chmod 0644 "$TMP/broken.toml"
buildah copy -q "$CONTAINER" "$TMP/broken.toml" /etc/gateway/broken.toml >/dev/null \
  || die "buildah copy of the broken config failed"
rc=0
# buildah reports the expected exit status 1 on stderr: shown only when the check fails.
out="$(in_image /gateway check --config /etc/gateway/broken.toml 2>"$TMP/err")" || rc=$?
step "in the image: /gateway check --config /etc/gateway/broken.toml -> exit $rc:" \
  "$(printf '%s\n' "$out" | head -1) ($(printf '%s\n' "$out" | wc -l) issues)"
if [ "$rc" != 1 ]; then
  cat "$TMP/err" >&2
  die "gateway check of a broken config exited $rc, expected 1"
fi
printf '%s\n' "$out" | grep -q 'parity' || die "the broken config's message does not name parity"

if [ "$keep" = 1 ]; then
  buildah tag "$IMAGE" "$KEEP_AS" || die "buildah tag $KEEP_AS failed"
  step "kept the image as $KEEP_AS"
fi
step "ok: image $image_size, binary $bin_bytes bytes;" \
  "musl release build ${build_seconds}s, buildah bud ${bud_seconds}s"
