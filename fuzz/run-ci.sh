#!/usr/bin/env bash
# A short, bounded fuzzing run of every cargo-fuzz target; exits non-zero on any crash, panic,
# timeout or out-of-memory, and prints the executions per target.
#
#   fuzz/run-ci.sh [SECONDS_PER_TARGET]      (default 40, or $FUZZ_SECONDS)
#   FUZZ_TARGETS="rtu slave" fuzz/run-ci.sh  (a subset)
#
# Toolchain: cargo-fuzz needs nightly flags (-Z...). The machines have only the stable toolchain,
# so the script runs cargo fuzz on stable with RUSTC_BOOTSTRAP=1 (set FUZZ_TOOLCHAIN=+nightly to
# use a nightly toolchain instead). It installs cargo-fuzz from crates.io when it is missing.
#
# Build: no sanitizer (-s none): the code under test is safe Rust (the workspace denies
# unsafe_code), so AddressSanitizer would find nothing a panic does not, at a third of the speed.
# Debug assertions and overflow checks are on (-a): an arithmetic overflow is a crash.
#
# Corpus: the committed seeds (fuzz/seeds/<target>/, written by make-seeds.py from
# proto-core/tests/vectors) are copied into fuzz/corpus/<target>/ (not committed), which keeps what
# the fuzzer found between runs on the same machine. A crash leaves its input in
# fuzz/artifacts/<target>/; reproduce it with `cargo fuzz run -s none -a <target> <file>` or add it
# to the seeds so that `cargo test -p proto-core fuzzing` runs it.
set -euo pipefail

cd "$(dirname "$0")"
SECONDS_PER_TARGET="${1:-${FUZZ_SECONDS:-40}}"
TOOLCHAIN="${FUZZ_TOOLCHAIN:-}"
if [[ -z "$TOOLCHAIN" ]]; then
    export RUSTC_BOOTSTRAP=1
fi

if ! cargo fuzz --version >/dev/null 2>&1; then
    echo "fuzz: installing cargo-fuzz" >&2
    cargo install cargo-fuzz --locked
fi

# shellcheck disable=SC2086 # $TOOLCHAIN is empty or one word
TARGETS="${FUZZ_TARGETS:-$(cargo $TOOLCHAIN fuzz list)}"
FLAGS=(-s none -a)

echo "fuzz: building ${TARGETS//$'\n'/ }"
# shellcheck disable=SC2086
cargo $TOOLCHAIN fuzz build "${FLAGS[@]}"

mkdir -p logs
status=0
summary=()
for target in $TARGETS; do
    mkdir -p "corpus/$target"
    if [[ -d "seeds/$target" ]]; then
        cp -n "seeds/$target"/* "corpus/$target/" 2>/dev/null || true
    fi
    log="logs/$target.log"
    echo "fuzz: $target for ${SECONDS_PER_TARGET}s"
    # -timeout: one input running longer than 5 s counts as a hang (a crash).
    # shellcheck disable=SC2086
    if cargo $TOOLCHAIN fuzz run "${FLAGS[@]}" "$target" "corpus/$target" -- \
        -max_total_time="$SECONDS_PER_TARGET" -timeout=5 -rss_limit_mb=2048 \
        -print_final_stats=1 >"$log" 2>&1; then
        result=ok
    else
        result=FAILED
        status=1
        echo "fuzz: $target FAILED; the end of its log:" >&2
        tail -n 40 "$log" >&2
        ls -1 "artifacts/$target" 2>/dev/null | sed 's/^/fuzz:   artifact /' >&2 || true
    fi
    execs=$(sed -n 's/^stat::number_of_executed_units: *//p' "$log" | tail -n 1)
    rate=$(sed -n 's/^stat::average_exec_per_sec: *//p' "$log" | tail -n 1)
    cov=$(grep -o 'cov: [0-9]*' "$log" | tail -n 1 || true)
    corpus=$(find "corpus/$target" -type f | wc -l)
    summary+=("$(printf '%-8s %-6s execs %-10s (%s/s)  %-10s corpus %s' \
        "$target" "$result" "${execs:-?}" "${rate:-?}" "${cov:-cov: ?}" "$corpus")")
done

echo "fuzz: summary (${SECONDS_PER_TARGET}s per target)"
printf '  %s\n' "${summary[@]}"
exit "$status"
