#!/bin/sh
# Every benchmark script once, in its shortest form, so none breaks unseen: `.ci/run` runs this
# after the test suite. It checks that each script runs to its end and prints its figures; it
# judges no figure (a target is a benchmark's, measured on a quiet machine, never a timed test).
# The Rust benchmarks (benches/*.rs) need no entry here: `cargo test --all-targets` runs each
# one's short smoke pass.
#
# Run from the crate root: sh benches/smoke.sh  (RIGSCRIPT=path runs them against that binary;
# by default the release build, made first if it is missing). Needs what the scripts need
# (mosquitto, valgrind, python3, GNU time, curl, socat): `.ci/run` installs them.
set -eu
if [ -z "${RIGSCRIPT:-}" ]; then
    cargo build --release --locked --quiet
    RIGSCRIPT=target/release/rigscript
fi
export RIGSCRIPT
log=$(mktemp -d)
trap 'rm -rf "$log"' EXIT
ran=0
failed=0

# One benchmark: a name, then the command. Its output is shown only when it fails, or when it
# prints nothing (a benchmark that measures nothing is broken too).
bench() {
    name=$1
    shift
    ran=$((ran + 1))
    began=$(date +%s)
    if "$@" >"$log/$name" 2>&1 && [ -s "$log/$name" ]; then
        printf 'bench smoke: %-18s ok (%s lines, %s s)\n' "$name" "$(wc -l <"$log/$name")" \
            "$(($(date +%s) - began))"
    else
        failed=$((failed + 1))
        printf 'bench smoke: %-18s FAILED after %s s; its output:\n' "$name" "$(($(date +%s) - began))"
        sed 's/^/    /' "$log/$name"
    fi
}

bench process sh benches/process.sh scripts/interlock.rhai 50ms 2s
bench web_viewers sh benches/web_viewers.sh scripts/interlock.rhai 2 2s
bench web_tricklers bash benches/web_tricklers.sh 4 3
bench mqtt_tick sh benches/mqtt_tick.sh scripts/interlock.rhai 2s 1
bench mqtt_lab env RIGS=2 SAMPLES=3 BASELINE=1 sh benches/mqtt_lab.sh
# The tick's instruction count needs symbols to find the loop's thread: the debug build has them.
bench tick_instructions env SHORT=10ms LONG=1s sh benches/tick_instructions.sh target/debug/rigscript
bench tick_journal env JOURNAL=1 SHORT=10ms LONG=1s sh benches/tick_instructions.sh target/debug/rigscript
bench stall sh benches/stall.sh "$RIGSCRIPT" 2
scratch=$(mktemp -d)
bench package_size env RIGSCRIPT_BIN="$RIGSCRIPT" CARGO_TARGET_DIR="$scratch" sh benches/package_size.sh
rm -rf "$scratch"
bench verify_seeds env SEEDS=1 PAR=1 JUDGE=0 SCRIPTS=tests/verify/counter_ack_keeps_waiting.rhai \
    sh benches/verify_seeds.sh

echo "bench smoke: $ran ran, $failed failed"
[ "$failed" -eq 0 ]
