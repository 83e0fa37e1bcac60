#!/bin/sh
# The planted-bug targets of `rigscript verify`, checked over many seeds: for each script in
# tests/verify/ and seeds 1..SEEDS, `rigscript verify FILE --seed S --json --out DIR` at the
# defaults (1000 runs, faults on, one job per core), then `rigscript test` on the test it
# wrote, which must fail naming the check verify reported (verify checks that itself; this is
# an independent look through the command a user runs). Targets, per script: found on at least
# 19 of 20 seeds (95 %), median time to find (the search's own wall time, `search_s`, before
# shrinking) at most 5 s, shrunk counterexamples of at most 6 events, every written test
# reproducing. Prints a table per script and a total, with the CPU time (user + sys, GNU
# time) of the whole verify, shrinking and its own reproduction check included; exits 1 when a
# target is missed, so it can be run as a check (JUDGE=0: only when a verify run failed, as in
# the smoke pass, which judges no figure).
#
# Run from the crate root: sh benches/verify_seeds.sh  (SEEDS=20; PAR=2 verifies at a time, at
# most 2; SCRIPTS="tests/verify/a.rhai ..." for some of them; KEEP=DIR keeps every JSON
# document, time and written test under DIR). RIGSCRIPT=path measures that binary instead of
# building the release one. Needs python3 (the JSON) and GNU time at /usr/bin/time.
set -eu
seeds=${SEEDS:-20}
par=${PAR:-2}
[ "$par" -gt 2 ] && par=2
[ "$par" -lt 1 ] && par=1
scripts=${SCRIPTS:-$(ls tests/verify/*.rhai)}
for tool in python3 /usr/bin/time; do
    if ! command -v "$tool" >/dev/null; then
        echo "verify_seeds.sh: needs $tool (apt-get install python3 time)" >&2
        exit 2
    fi
done
if [ -z "${RIGSCRIPT:-}" ]; then
    cargo build --release --quiet
fi
bin=${RIGSCRIPT:-target/release/rigscript}
if [ -n "${KEEP:-}" ]; then
    dir=$KEEP
    mkdir -p "$dir"
else
    dir=$(mktemp -d)
    trap 'rm -rf "$dir"' EXIT
fi
trap 'exit 130' INT TERM
echo "load before: $(uptime)"
: >"$dir/jobs"
for f in $scripts; do
    s=1
    while [ "$s" -le "$seeds" ]; do
        echo "$f $s" >>"$dir/jobs"
        s=$((s + 1))
    done
done

# one FILE SEED: one verify and the test it wrote; appends
# "NAME SEED FOUND SEARCH_S CPU_S WALL_S EVENTS REPRODUCED VERIFY_STATUS" to results.
one() {
    name=$(basename "$1" .rhai)
    base="$dir/$name-seed$2"
    status=0
    /usr/bin/time -f '%U %S %e' -o "$base.time" "$bin" verify "$1" --seed "$2" --json \
        --out "$base.out" >"$base.json" 2>"$base.err" || status=$?
    # FOUND SEARCH_S EVENTS TEST_FILE, then the text a failing `rigscript test` names the
    # check with (what the test runner prints for it: `invariant "NAME" is false`, or
    # `built-in check "NAME"`).
    python3 - "$base.json" >"$base.parsed" <<'PY' || printf "0 - - -\n-\n" >"$base.parsed"
import json, sys
doc = json.load(open(sys.argv[1]))
c = doc.get("counterexample")
if doc.get("result") != "counterexample" or not c:
    print("0", doc.get("search_s", "-"), "-", "-")
    print("-")
else:
    print("1", doc["search_s"], len(c["events"]), c.get("test_file") or "-")
    check = c["check"]
    print(check + " is false" if check.startswith("invariant ") else check)
PY
    read -r found search events test <"$base.parsed"
    want=$(sed -n 2p "$base.parsed")
    reproduced=-
    if [ "$found" = 1 ]; then
        reproduced=0
        if [ "$test" != - ] && [ -f "$test" ]; then
            if "$bin" test "$test" >"$base.test" 2>&1; then
                :
            elif grep -q '^FAIL ' "$base.test" && grep -qF "$want" "$base.test"; then
                reproduced=1
            fi
        fi
    fi
    # GNU time puts "Command exited with non-zero status N" before its line.
    read -r user sys wall <<EOF || { user=0; sys=0; wall=0; }
$(tail -n 1 "$base.time")
EOF
    cpu=$(awk -v u="$user" -v s="$sys" 'BEGIN { printf "%.2f", u + s }')
    echo "$name $2 $found $search $cpu $wall $events $reproduced $status" >>"$dir/results"
}

: >"$dir/results"
k=0
while [ "$k" -lt "$par" ]; do
    awk -v k="$k" -v n="$par" '(NR - 1) % n == k' "$dir/jobs" | while read -r f s; do
        one "$f" "$s"
    done &
    k=$((k + 1))
done
wait
echo "load after: $(uptime)"

python3 - "$dir/results" "$seeds" <<'PY'
import os, statistics, sys

rows = [line.split() for line in open(sys.argv[1])]
seeds = int(sys.argv[2])
by = {}
for name, seed, found, search, cpu, wall, events, repro, status in rows:
    by.setdefault(name, []).append(dict(
        seed=int(seed), found=found == "1", search=search, cpu=float(cpu), wall=float(wall),
        events=events, repro=repro, status=int(status)))

def line(label, rs):
    found = [r for r in rs if r["found"]]
    times = [float(r["search"]) for r in found]
    events = [int(r["events"]) for r in found]
    repro = sum(1 for r in found if r["repro"] == "1")
    misses = []
    if len(found) * 20 < 19 * len(rs):
        misses.append("found")
    if times and statistics.median(times) > 5.0:
        misses.append("median")
    if events and max(events) > 6:
        misses.append("events")
    if repro < len(found):
        misses.append("reproduced")
    if any(r["status"] not in (0, 1) for r in rs):
        misses.append("status")
    cells = [
        label,
        f"{len(found)}/{len(rs)}",
        f"{statistics.median(times):.2f}" if times else "-",
        f"{max(times):.2f}" if times else "-",
        str(max(events)) if events else "-",
        f"{repro}/{len(found)}",
        f"{statistics.median(r['cpu'] for r in rs):.2f}",
        f"{sum(r['cpu'] for r in rs):.1f}",
        " ".join(misses) or "ok",
    ]
    print("| " + " | ".join(cells) + " |")
    return misses

print(f"\nseeds 1-{seeds} each, at the defaults; times in seconds")
print("| script | found | median s | max s | max events | reproduced | median CPU s | CPU s | targets |")
print("|---|---|---|---|---|---|---|---|---|")
missed = False
for name in sorted(by):
    rs = sorted(by[name], key=lambda r: r["seed"])
    if line(name, rs):
        missed = True
    for r in rs:
        if not r["found"] or r["repro"] != "1" or r["status"] not in (0, 1):
            print(f"|   seed {r['seed']}: found {int(r['found'])}, reproduced {r['repro']}, "
                  f"verify status {r['status']} | | | | | | | | |")
everything = [r for rs in by.values() for r in rs]
if everything:
    line("total", everything)
if os.environ.get("JUDGE", "1") == "0":
    missed = any(r["status"] not in (0, 1) for r in everything)
sys.exit(1 if missed else 0)
PY
