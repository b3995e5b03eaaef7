#!/usr/bin/env bash
# Cross-compiles the static arm64 (aarch64-unknown-linux-musl) release binary of the gateway on an
# x86_64 host and runs it under qemu-user:
#
#   bash deploy/arm64-check.sh          # from anywhere; exits non-zero on the first failure
#
# Steps: install what is missing (rustup: the aarch64-unknown-linux-musl target; apt:
# gcc-aarch64-linux-gnu, the C compiler and linker for ring's C and assembly code, and
# qemu-user-static), build the release binary for the target, check that it is an AArch64 ELF
# with no interpreter and no shared libraries, then run it under qemu-aarch64-static:
# `gateway --version` prints the workspace version, `gateway check` of
# deploy/gateway.example.toml prints `ok: ...` and exits 0, a broken copy exits 1.
#
# The cross compiler and linker are set for this build only, through the environment
# (CC_aarch64_unknown_linux_musl, CARGO_TARGET_AARCH64_UNKNOWN_LINUX_MUSL_LINKER): no
# .cargo/config that native builds would read. The Rust target ships musl's libc and start files
# (self-contained linking); the GNU cross gcc only drives the link and compiles ring's C, which
# uses no libc headers that differ between glibc and musl. deploy/Dockerfile does the same for
# `docker buildx build --platform linux/arm64`. CARGO_TARGET_DIR is honoured (default: target/ of
# the repository; the cross build goes to its aarch64-unknown-linux-musl/ directory).
set -euo pipefail

DEPLOY="$(cd "$(dirname "$0")" && pwd)"
ROOT="$(dirname "$DEPLOY")"
TARGET=aarch64-unknown-linux-musl
TARGET_DIR="${CARGO_TARGET_DIR:-$ROOT/target}"
BIN="$TARGET_DIR/$TARGET/release/gateway"
CROSS_GCC=aarch64-linux-gnu-gcc
QEMU=qemu-aarch64-static

TMP="$(mktemp -d)"
trap 'rm -rf "$TMP"' EXIT

die() {
  echo "arm64-check: FAIL: $*" >&2
  exit 1
}
step() { echo "arm64-check: $*"; }
have() { command -v "$1" >/dev/null 2>&1; }

SUDO=""
if [ "$(id -u)" != 0 ] && have sudo; then SUDO="sudo"; fi
apt_install() {
  step "apt-get install $*"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "$@"
}

# --- tools -----------------------------------------------------------------------------------
have readelf || apt_install binutils
have "$CROSS_GCC" || apt_install gcc-aarch64-linux-gnu libc6-dev-arm64-cross
have "$QEMU" || apt_install qemu-user-static
if ! rustup target list --installed | grep -qx "$TARGET"; then
  step "rustup target add $TARGET"
  rustup target add "$TARGET"
fi

# --- the static arm64 binary -----------------------------------------------------------------
step "cargo build --locked --release --target $TARGET -p gateway --bin gateway"
t0=$SECONDS
(cd "$ROOT" && CARGO_TARGET_DIR="$TARGET_DIR" \
  CC_aarch64_unknown_linux_musl="$CROSS_GCC" \
  AR_aarch64_unknown_linux_musl=aarch64-linux-gnu-ar \
  CARGO_TARGET_AARCH64_UNKNOWN_LINUX_MUSL_LINKER="$CROSS_GCC" \
  cargo build --locked --release --target "$TARGET" -p gateway --bin gateway) \
  || die "arm64 musl release build failed"
build_seconds=$((SECONDS - t0))
[ -x "$BIN" ] || die "$BIN missing after the build"

machine="$(readelf -hW "$BIN" | sed -n 's/^ *Machine: *//p')"
[ "$machine" = "AArch64" ] || die "$BIN is built for '$machine', expected AArch64"
# Static: no program interpreter (PT_INTERP) and no shared library (DT_NEEDED).
if readelf -lW "$BIN" | grep -q 'INTERP'; then
  die "$BIN has a program interpreter: $(readelf -lW "$BIN" | grep -A1 INTERP)"
fi
if readelf -dW "$BIN" | grep -q '(NEEDED)'; then
  die "$BIN needs shared libraries: $(readelf -dW "$BIN" | grep '(NEEDED)')"
fi
bin_bytes="$(stat -c %s "$BIN")"
step "static AArch64 binary: $BIN ($bin_bytes bytes, built in ${build_seconds}s)"

# --- under qemu-user -------------------------------------------------------------------------
version="$(sed -n 's/^version = "\(.*\)"$/\1/p' "$ROOT/Cargo.toml" | head -1)"
[ -n "$version" ] || die "no version in Cargo.toml"
out="$("$QEMU" "$BIN" --version)" || die "gateway --version failed under $QEMU: $out"
step "under $QEMU: gateway --version -> $out"
[ "$out" = "gateway $version" ] || die "gateway --version printed '$out', expected 'gateway $version'"

# The example as shipped (its REST token line stays commented until the operator makes the file),
# beside the template directory it names (template_dirs = ["templates"], taken from its directory).
cp "$DEPLOY/gateway.example.toml" "$TMP/gateway.toml"
cp -r "$DEPLOY/templates" "$TMP/templates"
rc=0
out="$("$QEMU" "$BIN" check --config "$TMP/gateway.toml" 2>&1)" || rc=$?
step "under $QEMU: gateway check --config <example> -> exit $rc: $(printf '%s\n' "$out" | head -1)"
[ "$rc" = 0 ] || die "gateway check of the example config exited $rc: $out"
case "$out" in ok:*) ;; *) die "gateway check did not print 'ok: ...': $out" ;; esac

sed 's/^parity = "even"$/parity = "sometimes"/' "$TMP/gateway.toml" >"$TMP/broken.toml"
rc=0
out="$("$QEMU" "$BIN" check --config "$TMP/broken.toml" 2>&1)" || rc=$?
step "under $QEMU: gateway check --config <broken copy> -> exit $rc"
[ "$rc" = 1 ] || die "gateway check of a broken config exited $rc, expected 1: $out"
printf '%s\n' "$out" | grep -q 'parity' || die "the broken config's message does not name parity"

step "ok: arm64 binary $bin_bytes bytes, built in ${build_seconds}s, runs under $QEMU"
