#!/bin/sh
# CPU use while idling and peak resident memory of a real `rigscript run` process on the
# simulated devices, measured with GNU time. Targets: at most 1% of a core idling at a 50 ms
# period; at most 20 MB resident.
#
# Run from the crate root: sh benches/process.sh [SCRIPT] [PERIOD] [DURATION]
# (defaults: scripts/interlock.rhai, which polls its inputs every tick, 50ms, 20s);
# RIGSCRIPT=path measures that binary instead of building the release one.
set -eu
script=${1:-scripts/interlock.rhai}
period=${2:-50ms}
duration=${3:-20s}
if [ ! -x /usr/bin/time ]; then
    echo "process.sh: needs GNU time at /usr/bin/time (apt-get install time)" >&2
    exit 2
fi
if [ -z "${RIGSCRIPT:-}" ]; then
    cargo build --release --quiet
fi
bin=${RIGSCRIPT:-target/release/rigscript}
out=$(mktemp)
# A rig directory of its own: its socket cannot meet another run's of the same script (the
# test suite runs beside this in .ci/run).
rigs=$(mktemp -d)
trap 'rm -rf "$out" "$rigs"' EXIT
XDG_RUNTIME_DIR=$rigs /usr/bin/time -v -o "$out" "$bin" run "$script" --sim --quiet \
    --period "$period" --for "$duration" >/dev/null 2>&1 || true
awk -v script="$script" -v period="$period" '
    /User time/ { user = $NF }
    /System time/ { sys = $NF }
    /Elapsed \(wall clock\)/ {
        n = split($NF, t, ":"); wall = 0
        for (i = 1; i <= n; i++) wall = wall * 60 + t[i]
    }
    /Maximum resident set size/ { rss = $NF }
    /Exit status/ { status = $NF }
    END {
        printf "%s at %s: %.2f s CPU (user %.2f, sys %.2f) over %.1f s = %.2f%% of a core\n",
            script, period, user + sys, user, sys, wall, 100 * (user + sys) / wall
        printf "peak resident memory: %.1f MB (exit status %s)\n", rss / 1024, status
    }' "$out"
