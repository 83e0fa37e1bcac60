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
# With MQTT=1, rig.toml has `[mqtt]` to a Mosquitto of the script's own on a free loopback port,
# up for the whole run: the client connects, publishes the rig's status and the module's state
# once, then has nothing to tell (no record, the inputs do not change), as a run without
# records. Its connection takes valgrind a while, so the start-up run lasts 2 s (the measured
# one 6 s) and both must have connected (the broker's log is checked). Without MQTT=1 the same
# durations are had with SHORT=2s LONG=6s, for a like-for-like pair.
#
# With JOURNAL=1 the run writes a journal (`run --journal`): the inputs do not change, so what
# it adds to the loop's thread is one store a tick (events carry their tick) and an entry for
# each overrun (its own thread's writes count among the other threads). At the default period
# of 1 µs every tick overruns, so measure it with PERIOD=5ms (a poll at 115200 baud takes about
# 3 ms), against a run without it at the same period.
#
# Besides all threads' count it prints the scan loop's thread alone (callgrind
# --separate-threads; the thread that runs `Runner::run`, kept out of line (#[inline(never)])
# so that its symbol survives a build of one codegen unit: the ticks and the requests served
# between them) a tick, and the other threads' instructions a second of the measured run.
#
# Run from the crate root: sh benches/tick_instructions.sh [BINARY]
# (default target/profiling/rigscript, built first with `cargo build --profile profiling`: the
# release code with debug info, so a kept callgrind output shows source lines; give another
# build to compare: it is then run as it is, simulator included). `.ci/run` runs it once as a
# smoke check on the debug build with SHORT=10ms LONG=1s.
# Needs valgrind (apt-get install valgrind).
set -eu
binary=${1:-target/profiling/rigscript}
if ! command -v valgrind >/dev/null; then
    echo "tick_instructions.sh: needs valgrind (apt-get install valgrind)" >&2
    exit 2
fi
if [ $# -eq 0 ]; then
    cargo build --profile profiling --quiet
fi
dir=$(mktemp -d)
broker=
trap 'kill "$sim" $broker 2>/dev/null; rm -rf "$dir"' EXIT
"$binary" sim c29u --baud 115200 --link "$dir/pty" >/dev/null 2>&1 &
sim=$!
for _ in 1 2 3 4 5 6 7 8 9 10; do [ -e "$dir/pty" ] && break; sleep 0.2; done
printf '[devices.io]\nkind = "trp-c29u"\nport = "%s"\nbaud = 115200\n' "$dir/pty" >"$dir/rig.toml"
echo 'io.on_rise(0, || {});' >"$dir/poll.rhai"
# Builds before the guardian have no such flag (and no guardian).
no_guardian=$("$binary" run --help | grep -q -- --no-guardian && echo --no-guardian || true)
short=${SHORT:-10ms}
long=${LONG:-4s}
if [ "${MQTT:-0}" = 1 ]; then
    if ! command -v mosquitto >/dev/null; then
        echo "tick_instructions.sh: MQTT=1 needs mosquitto (apt-get install mosquitto)" >&2
        exit 2
    fi
    short=${SHORT:-2s}
    long=${LONG:-6s}
    port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
    printf 'listener %s 127.0.0.1\nallow_anonymous true\npersistence false\n' "$port" \
        >"$dir/mosquitto.conf"
    mosquitto -c "$dir/mosquitto.conf" >"$dir/mosquitto.log" 2>&1 &
    broker=$!
    printf '[mqtt]\nurl = "mqtt://127.0.0.1:%s"\nrig = "tick"\noutbox = "%s/outbox"\n' \
        "$port" "$dir" >>"$dir/rig.toml"
fi
# Prints "TICKS INSTRUCTIONS LOOP_THREAD_INSTRUCTIONS" for a run of DURATION.
count() {
    rm -f "$dir"/cg.*
    # --no-guardian: valgrind follows the fork, and the guardian's own count (it only waits)
    # would be the last one printed; it costs the tick nothing.
    if [ "${2:-}" = watch ]; then watch_rig >/dev/null 2>&1 & fi
    XDG_RUNTIME_DIR="$dir" valgrind --tool=callgrind --separate-threads=yes \
        --callgrind-out-file="$dir/cg.%p" "$binary" run "$dir/poll.rhai" \
        --config "$dir/rig.toml" --period "${PERIOD:-1us}" --wake-latency off --quiet --stats --for "$1" \
        $no_guardian $journal 2>&1 |
        awk '/^ticks:/ { t = $2 } /Collected :/ { gsub(",", "", $NF); i = $NF } END { printf "%s %s ", t, i }'
    # The loop's thread: its file names Runner::run.
    loop=
    for f in "$dir"/cg.*-*; do
        if grep -q 'Runner<P>::run$' "$f"; then loop=$(awk '/^totals:/ { print $2 }' "$f"); fi
    done
    if [ -z "$loop" ]; then
        echo "tick_instructions.sh: no thread ran Runner::run (is it still #[inline(never)]?)" >&2
        exit 1
    fi
    echo "$loop"
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
journal=
[ "${JOURNAL:-0}" = 1 ] && journal="--journal $dir/journal"
set -- $(count "$short") $(count "$long" $mode)
if [ -n "$broker" ]; then
    connected=$(grep -c 'New client connected' "$dir/mosquitto.log" || true)
    if [ "$connected" -lt 2 ]; then
        echo "tick_instructions.sh: the client connected in $connected of the 2 runs" >&2
        exit 1
    fi
fi
seconds() { awk -v d="$1" 'BEGIN { n = d + 0; sub(/^[0-9.]+/, "", d)
    print n * (d == "ms" ? 0.001 : d == "us" ? 0.000001 : d == "m" ? 60 : 1) }'; }
awk -v t0="$1" -v i0="$2" -v l0="$3" -v t1="$4" -v i1="$5" -v l1="$6" \
    -v s0="$(seconds "$short")" -v s1="$(seconds "$long")" 'BEGIN {
    printf "%d ticks, %.0f instructions a tick (start-up of %.1f M taken off)\n",
        t1 - t0, (i1 - i0) / (t1 - t0), i0 / 1e6
    printf "the loop'"'"'s thread: %.0f a tick; the other threads: %.0f a second\n",
        (l1 - l0) / (t1 - t0), ((i1 - l1) - (i0 - l0)) / (s1 - s0)
}'
