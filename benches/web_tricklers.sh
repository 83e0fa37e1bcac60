#!/bin/bash
# Slow clients against the web page: N clients trickle a request one byte every 0.3 s (each
# connects again when let go), while the owner asks GET /api/state TRIES times; prints how
# many were answered 200 within 2 s (target: at least 90 %), and the answers' times.
#
# Run from the crate root: bash benches/web_tricklers.sh [TRICKLERS] [TRIES]
# (defaults: 40, 50); RIGSCRIPT=path measures that binary instead of building the release one.
# Bash: the tricklers use its /dev/tcp.
set -eu
tricklers=${1:-40}
tries=${2:-50}
if [ -z "${RIGSCRIPT:-}" ]; then
    cargo build --release --quiet
fi
bin=${RIGSCRIPT:-target/release/rigscript}
dir=$(mktemp -d)
trap 'kill $(jobs -p) 2>/dev/null || true; rm -rf "$dir"' EXIT

XDG_RUNTIME_DIR=$dir "$bin" run scripts/interlock.rhai --sim --quiet --ui 127.0.0.1:0 \
    >"$dir/log" 2>&1 &
addr=
while [ -z "$addr" ]; do
    sleep 0.2
    addr=$(sed -n 's|.*ui: http://\([^/]*\)/.*|\1|p' "$dir/log" | head -n 1)
done
port=${addr##*:}

# One trickler: a request that never ends, again whenever the server lets it go.
trickle() {
    while :; do
        exec 3<>"/dev/tcp/127.0.0.1/$port" || { sleep 0.1; continue; }
        printf 'GET /api/state HTTP/1.1\r\nX-Slow: ' >&3 2>/dev/null || true
        while printf a >&3 2>/dev/null; do sleep 0.3; done
        exec 3>&-
    done
}
i=0
while [ "$i" -lt "$tricklers" ]; do
    trickle &
    i=$((i + 1))
done
sleep 2

i=0
while [ "$i" -lt "$tries" ]; do
    curl -s -o /dev/null --max-time 10 -w '%{http_code} %{time_total}\n' \
        "http://$addr/api/state" >>"$dir/answers" || echo "000 10" >>"$dir/answers"
    sleep 0.2
    i=$((i + 1))
done
sort -k2 -n "$dir/answers" | awk -v n="$tries" -v t="$tricklers" '
    { code[NR] = $1; time[NR] = $2; if ($1 == 200 && $2 <= 2) ok++; if ($1 != 200) bad[$1]++ }
    END {
        printf "%d tricklers: %d of %d GET /api/state answered 200 within 2 s (%.0f %%)\n", t, ok, n, 100 * ok / n
        printf "time p50 %.3f s, p90 %.3f s, max %.3f s\n", time[int(n * 0.5) + 0], time[int(n * 0.9) + 0], time[n]
        for (c in bad) printf "status %s: %d\n", c, bad[c]
    }'
