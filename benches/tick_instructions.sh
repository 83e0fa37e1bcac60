#!/bin/sh
# Instructions a scan tick runs (callgrind's count, exact and free of a virtual machine's noise)
# when `rigscript run` polls a simulated TRP-C29U's inputs as fast as the line allows (Modbus
# RTU at 115200 baud on a pty, frame gap kept, one `io.on_rise` handler that never fires): the
# steady-state cost of a tick, exchange included, system calls excluded. Start-up is measured by
# a run of one tick and taken off.
#
# With WATCHERS=1, a `status --watch` client and an event-stream subscriber (socat) are attached
# for the measured run: the count then includes every thread of the runner (the socket's
# threads serving them too), an upper bound on what watching costs the loop.
#
# Run from the crate root: sh benches/tick_instructions.sh [BINARY]
# (default target/profiling/rigscript, `cargo build --profile profiling`: the release code with
# debug info, so a kept callgrind output shows source lines; give another build to compare).
# Needs valgrind (apt-get install valgrind).
set -eu
binary=${1:-target/profiling/rigscript}
if ! command -v valgrind >/dev/null; then
    echo "tick_instructions.sh: needs valgrind (apt-get install valgrind)" >&2
    exit 2
fi
cargo build --profile profiling --quiet
dir=$(mktemp -d)
trap 'kill "$sim" 2>/dev/null; rm -rf "$dir"' EXIT
target/profiling/rigscript sim c29u --baud 115200 --link "$dir/pty" >/dev/null 2>&1 &
sim=$!
for _ in 1 2 3 4 5 6 7 8 9 10; do [ -e "$dir/pty" ] && break; sleep 0.2; done
printf '[devices.io]\nkind = "trp-c29u"\nport = "%s"\nbaud = 115200\n' "$dir/pty" >"$dir/rig.toml"
echo 'io.on_rise(0, || {});' >"$dir/poll.rhai"
# Builds before the guardian have no such flag (and no guardian).
no_guardian=$("$binary" run --help | grep -q -- --no-guardian && echo --no-guardian || true)
# Prints "TICKS INSTRUCTIONS" for a run of DURATION.
count() {
    # --no-guardian: valgrind follows the fork, and the guardian's own count (it only waits)
    # would be the last one printed; it costs the tick nothing.
    if [ "${2:-}" = watch ]; then watch_rig >/dev/null 2>&1 & fi
    XDG_RUNTIME_DIR="$dir" valgrind --tool=callgrind --callgrind-out-file=/dev/null \
        "$binary" run "$dir/poll.rhai" \
        --config "$dir/rig.toml" --period 1us --wake-latency off --quiet --stats --for "$1" \
        $no_guardian 2>&1 |
        awk '/^ticks:/ { t = $2 } /Collected :/ { gsub(",", "", $NF); i = $NF } END { print t, i }'
}
# Attaches the watchers once the run's socket is there; they end with the run.
watch_rig() {
    sock="$dir/rigscript/rig.sock"
    for _ in $(seq 1 300); do [ -S "$sock" ] && break; sleep 0.1; done
    (printf '{"request":"subscribe"}\n'; sleep 30) | socat - "UNIX-CONNECT:$sock" >/dev/null 2>&1 &
    XDG_RUNTIME_DIR="$dir" timeout 30 "$binary" status rig --watch >/dev/null 2>&1 &
}
mode=
[ "${WATCHERS:-0}" = 1 ] && mode=watch
set -- $(count 10ms) $(count 4s $mode)
awk -v t0="$1" -v i0="$2" -v t1="$3" -v i1="$4" 'BEGIN {
    printf "%d ticks, %.0f instructions a tick (start-up of %.1f M taken off)\n",
        t1 - t0, (i1 - i0) / (t1 - t0), i0 / 1e6
}'
