#!/bin/sh
# What `[mqtt]` costs the scan loop in wall time when the run publishes no records: a real
# `rigscript run --sim --config` of SCRIPT (default scripts/interlock.rhai, which reads its
# inputs every 20 ms tick and sets outputs), without `[mqtt]` and with it (a Mosquitto of its
# own on a free loopback port, up the whole run), ROUNDS times each, alternating so the
# machine's load falls on both alike. Prints each run's `--stats` tick work and jitter
# (target: with MQTT tick work at most 5 µs more, jitter p99 within the runs' spread). The
# instruction count of the same comparison, free of the machine's load, is
# `MQTT=1 sh benches/tick_instructions.sh`.
#
# Run from the crate root: sh benches/mqtt_tick.sh [SCRIPT] [DURATION] [ROUNDS]
# (defaults: scripts/interlock.rhai, 20s, 2); RIGSCRIPT=path measures that binary instead of
# building the release one. Needs mosquitto.
set -eu
script=${1:-scripts/interlock.rhai}
duration=${2:-20s}
rounds=${3:-2}
if ! command -v mosquitto >/dev/null; then
    echo "mqtt_tick.sh: needs mosquitto (apt-get install mosquitto)" >&2
    exit 2
fi
if [ -z "${RIGSCRIPT:-}" ]; then
    cargo build --release --quiet
fi
bin=${RIGSCRIPT:-target/release/rigscript}
dir=$(mktemp -d)
broker=
trap '[ -n "$broker" ] && kill "$broker" 2>/dev/null; rm -rf "$dir"' EXIT
port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
printf 'listener %s 127.0.0.1\nallow_anonymous true\npersistence false\n' "$port" >"$dir/mosquitto.conf"
mosquitto -c "$dir/mosquitto.conf" >"$dir/mosquitto.log" 2>&1 &
broker=$!
devices='[devices.io]\nkind = "trp-c29u"\nport = "/dev/ttyUSB0"\n[devices.panel]\nkind = "trc1000"\n'
printf "name = \"off\"\n$devices" >"$dir/off.toml"
printf "name = \"on\"\n[mqtt]\nurl = \"mqtt://127.0.0.1:%s\"\nrig = \"tick\"\noutbox = \"%s/outbox\"\n$devices" \
    "$port" "$dir" >"$dir/on.toml"
echo "load before: $(uptime)"
i=1
while [ "$i" -le "$rounds" ]; do
    for mode in off on; do
        XDG_RUNTIME_DIR=$dir "$bin" run "$script" --sim --config "$dir/$mode.toml" --quiet \
            --stats --for "$duration" >"$dir/log" 2>&1 || true
        printf '%-3s  ' "$mode"
        grep -E '^(tick work|jitter):' "$dir/log" | tr '\n' ' '
        grep -q 'mqtt: connected' "$dir/log" && printf '(connected)'
        echo
    done
    i=$((i + 1))
done
echo "load after: $(uptime)"
