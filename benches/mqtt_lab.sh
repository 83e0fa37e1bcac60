#!/bin/sh
# A lab on one broker: RIGS simulated rigs (`rigscript run --sim --config`, one process each,
# `[mqtt]` to a Mosquitto of our own on a free loopback port), and BASELINE more without
# `[mqtt]` to compare memory with. Target: from an input change to its retained
# `rigscript/NAME/state/io` message at a subscriber, p99 at most 50 ms; memory per rig reported.
#
# Each round sets DI0 of every rig at once (the control socket's `drive` request, the one
# `rigscript drive NAME set-inputs io BYTE` sends, all written before any answer is read),
# then waits for each rig's state message with that DI byte (at most 2 s: after that it counts
# as missed), then pauses 100-300 ms, so rounds fall at random phases of the rigs' ticks and of
# the client's 50 ms gap between state publications. A sample's latency runs from just before
# its request is written (the change is applied at the loop's next tick boundary, so this
# includes up to a period of waiting for it) to the subscriber's receipt (mosquitto_sub's own
# time stamp, `%U`). Memory: VmRSS and VmHWM of each process after the rounds.
#
# Run from the crate root: sh benches/mqtt_lab.sh  (RIGS=50 SAMPLES=100 BASELINE=5 PERIOD=20ms;
# RIGS=5 SAMPLES=10 for a quick look). RIGSCRIPT=path measures that binary instead of building
# the release one. Needs mosquitto, mosquitto_sub and python3.
set -eu
rigs=${RIGS:-50}
samples=${SAMPLES:-100}
baseline=${BASELINE:-5}
period=${PERIOD:-20ms}
for tool in mosquitto mosquitto_sub python3; do
    if ! command -v "$tool" >/dev/null; then
        echo "mqtt_lab.sh: needs $tool (apt-get install mosquitto mosquitto-clients python3)" >&2
        exit 2
    fi
done
if [ -z "${RIGSCRIPT:-}" ]; then
    cargo build --release --quiet
fi
bin=${RIGSCRIPT:-target/release/rigscript}
dir=$(mktemp -d)
pids=
broker=
cleanup() {
    # shellcheck disable=SC2086
    [ -n "$pids" ] && kill $pids 2>/dev/null
    [ -n "$broker" ] && kill "$broker" 2>/dev/null
    wait 2>/dev/null
    rm -rf "$dir"
}
trap cleanup EXIT
trap 'exit 130' INT TERM

port=$(python3 -c 'import socket; s = socket.socket(); s.bind(("127.0.0.1", 0)); print(s.getsockname()[1])')
printf 'listener %s 127.0.0.1\nallow_anonymous true\npersistence false\n' "$port" >"$dir/mosquitto.conf"
mosquitto -c "$dir/mosquitto.conf" >"$dir/mosquitto.log" 2>&1 &
broker=$!
echo 'io.on_rise(0, |ch| {});' >"$dir/lab.rhai"
echo "load before: $(uptime)"

# rig NAME MQTT(0|1): starts one rig; its pid goes to pids and NAME PID MQTT to rigs.list.
rig() {
    {
        printf 'name = "%s"\nperiod = "%s"\n' "$1" "$period"
        if [ "$2" = 1 ]; then
            printf '[mqtt]\nurl = "mqtt://127.0.0.1:%s"\nrig = "%s"\noutbox = "%s/outbox"\n' \
                "$port" "$1" "$dir"
        fi
        printf '[devices.io]\nkind = "trp-c29u"\nport = "/dev/ttyUSB0"\n'
    } >"$dir/$1.toml"
    XDG_RUNTIME_DIR=$dir "$bin" run "$dir/lab.rhai" --sim --config "$dir/$1.toml" \
        --quiet --stats >"$dir/$1.log" 2>&1 &
    pids="$pids $!"
    echo "$1 $! $2" >>"$dir/rigs.list"
}
i=1
while [ "$i" -le "$rigs" ]; do
    rig "$(printf 'lab%02d' "$i")" 1
    i=$((i + 1))
done
i=1
while [ "$i" -le "$baseline" ]; do
    rig "$(printf 'base%02d' "$i")" 0
    i=$((i + 1))
done

python3 - "$dir" "$port" "$samples" <<'PY'
import json, os, random, socket, subprocess, sys, threading, time

dir, port, samples = sys.argv[1], sys.argv[2], int(sys.argv[3])
rigs = [line.split() for line in open(os.path.join(dir, "rigs.list"))]
lab = [name for name, _, mqtt in rigs if mqtt == "1"]

# Every state message as (arrival, DI byte), by rig; the subscriber stamps the arrival.
seen = {name: [] for name in lab}
cv = threading.Condition()
sub = subprocess.Popen(
    ["mosquitto_sub", "-h", "127.0.0.1", "-p", port, "-q", "1",
     "-t", "rigscript/+/state/io", "-F", "%U %t %p"],
    stdout=subprocess.PIPE, text=True, bufsize=1)

def follow():
    for line in sub.stdout:
        try:
            at, topic, payload = line.rstrip("\n").split(" ", 2)
            name = topic.split("/")[1]
            inputs = json.loads(payload).get("inputs")
        except (ValueError, IndexError):
            continue
        with cv:
            if name in seen:
                seen[name].append((float(at), inputs))
                cv.notify_all()

threading.Thread(target=follow, daemon=True).start()

def wait_until(ready, limit):
    end = time.time() + limit
    with cv:
        while not ready():
            left = end - time.time()
            if left <= 0:
                return False
            cv.wait(left)
    return True

# Every lab rig connected and its first state published (retained, or live).
if not wait_until(lambda: all(seen[n] for n in lab), 120):
    missing = [n for n in lab if not seen[n]]
    sys.exit(f"mqtt_lab: no state message from {len(missing)} rigs: {' '.join(missing[:5])} ...")
time.sleep(1)

socks = {}
for name, _, _ in rigs:
    path = os.path.join(dir, "rigscript", name + ".sock")
    for _ in range(300):
        if os.path.exists(path):
            break
        time.sleep(0.1)
    s = socket.socket(socket.AF_UNIX)
    s.connect(path)
    socks[name] = (s, s.makefile("r"))

latency, answered, missed = [], [], 0
for k in range(samples):
    value = 1 - k % 2
    request = json.dumps({"request": "drive", "device": "io", "action": "set_inputs",
                          "value": value}).encode() + b"\n"
    order = list(socks)
    random.shuffle(order)
    with cv:
        mark = {n: len(seen[n]) for n in lab}
    sent = {}
    for name in order:
        sent[name] = time.time()
        socks[name][0].sendall(request)
    for name in order:
        reply = json.loads(socks[name][1].readline())
        if not reply.get("ok"):
            sys.exit(f"mqtt_lab: {name} refused the drive: {reply.get('error')}")
        answered.append(time.time() - sent[name])

    def arrival(name):
        for at, inputs in seen[name][mark[name]:]:
            if inputs == value:
                return at
        return None

    wait_until(lambda: all(arrival(n) is not None for n in lab), 2.0)
    with cv:
        for name in lab:
            at = arrival(name)
            if at is None:
                missed += 1
            else:
                latency.append(at - sent[name])
    time.sleep(random.uniform(0.1, 0.3))
sub.terminate()

def pct(xs, p):
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(p / 100 * len(xs)))] * 1000 if xs else float("nan")

print(f"{len(lab)} rigs on one broker, {samples} rounds: {len(latency)} samples, {missed} missed")
print("input change to state message: p50 %.1f ms, p99 %.1f ms, max %.1f ms"
      % (pct(latency, 50), pct(latency, 99), pct(latency, 100)))
print("drive answered (change applied): p50 %.1f ms, p99 %.1f ms"
      % (pct(answered, 50), pct(answered, 99)))

def status(pid, key):
    for line in open(f"/proc/{pid}/status"):
        if line.startswith(key + ":"):
            return int(line.split()[1])
    return 0

for label, flag in (("with [mqtt]", "1"), ("without", "0")):
    pids = [pid for _, pid, mqtt in rigs if mqtt == flag]
    if not pids:
        continue
    rss = [status(p, "VmRSS") / 1024 for p in pids]
    hwm = [status(p, "VmHWM") / 1024 for p in pids]
    print("memory per rig %-12s (%2d): VmRSS mean %.1f MiB (max %.1f), VmHWM mean %.1f MiB (max %.1f)"
          % (label, len(pids), sum(rss) / len(rss), max(rss), sum(hwm) / len(hwm), max(hwm)))
PY
echo "load after: $(uptime)"
