#!/bin/sh
# The web page's cost: the bytes of a first page load (the page, uPlot, its style sheet and
# the page's first three API answers; target at most 200 KB), and the tick work and jitter of
# a real `rigscript run --sim --ui` with no viewer and with N viewers following the event
# stream (target: 10 viewers add at most 5 % to tick work, jitter p99 within noise).
#
# Run from the crate root: sh benches/web_viewers.sh [SCRIPT] [VIEWERS] [DURATION]
# (defaults: scripts/interlock.rhai, which polls its inputs every 20 ms tick, 10, 30s);
# RIGSCRIPT=path measures that binary instead of building the release one.
set -eu
script=${1:-scripts/interlock.rhai}
viewers=${2:-10}
duration=${3:-30s}
if [ -z "${RIGSCRIPT:-}" ]; then
    cargo build --release --quiet
fi
bin=${RIGSCRIPT:-target/release/rigscript}
dir=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$dir"' EXIT

# One run with `n` viewers; prints its --stats lines for tick work and jitter.
run() {
    n=$1
    XDG_RUNTIME_DIR=$dir "$bin" run "$script" --sim --quiet --stats --for "$duration" \
        --ui 127.0.0.1:0 >"$dir/log.$n" 2>&1 &
    pid=$!
    addr=
    while [ -z "$addr" ]; do
        sleep 0.2
        addr=$(sed -n 's|.*ui: http://\([^/]*\)/.*|\1|p' "$dir/log.$n" | head -n 1)
    done
    if [ "$n" = 0 ]; then
        total=0
        for path in / /uplot.js /uplot.css /api/layout /api/history /api/state; do
            bytes=$(curl -s "http://$addr$path" | wc -c)
            total=$((total + bytes))
            printf '  %-12s %7d bytes\n' "$path" "$bytes"
        done
        printf 'first page load: %d bytes (%d KB)\n' "$total" $((total / 1024))
    fi
    i=0
    while [ "$i" -lt "$n" ]; do
        curl -sN "http://$addr/api/events" >/dev/null &
        i=$((i + 1))
    done
    wait "$pid" || true
    printf '%s viewers: ' "$n"
    grep -E '^(tick work|jitter):' "$dir/log.$n" | tr '\n' ' '
    echo
}

run 0
run "$viewers"
