#!/bin/sh
# A stuck scan loop -> the module read back safe: how long after the loop stops turning the
# simulated TRP-C29U (a pty, Modbus RTU at 115200 baud) holds its safe value again, with
# `stall = "1s"`. Target: within stall + 0.5 s, p99 over the runs.
#
# Each run: a rig drives the module's outputs to 0x0F; the runner (the guardian's child) is then
# frozen with SIGSTOP at t0, exactly as a handler stuck in one operation freezes its loop (no
# beat after it). The module's state is polled every 2 ms from t0 until its outputs read 0x00
# again; the guardian must also exit 6 naming the stall. Prints each run's time with
# VERBOSE=1, then p50, p99 and the worst.
#
# Run from the crate root: sh benches/stall.sh [BINARY] [RUNS]
# (default target/release/rigscript, built first, and 20 runs; `.ci/run` runs 2 against the
# debug build as a smoke check).
set -eu
binary=${1:-target/release/rigscript}
runs=${2:-20}
if [ "$binary" = target/release/rigscript ]; then
    cargo build --release --quiet
fi
exec python3 - "$binary" "$runs" <<'EOF'
import os, signal, subprocess, sys, tempfile, time, json

binary, runs = sys.argv[1], int(sys.argv[2])
STALL = 1.0


def one(dir):
    sim = subprocess.Popen([binary, "sim", "c29u", "--protocol", "modbus", "--id", "1"],
                           stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                           stderr=subprocess.DEVNULL, text=True)
    try:
        path = sim.stdout.readline().strip()

        def state():
            sim.stdin.write("state\n")
            sim.stdin.flush()
            return json.loads(sim.stdout.readline())

        config = os.path.join(dir, "rig.toml")
        with open(config, "w") as f:
            f.write('period = "20ms"\nstall = "1s"\n[devices.io]\nkind = "trp-c29u"\n'
                    f'port = "{path}"\nsafe_value = 0x00\n')
        script = os.path.join(dir, "work.rhai")
        with open(script, "w") as f:
            f.write('io.outputs = 0x0F;\nevery("100ms", || {});\n')
        run = subprocess.Popen([binary, "run", "--config", config, script],
                               stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                               env=dict(os.environ, XDG_RUNTIME_DIR=dir))
        try:
            deadline = time.monotonic() + 20
            while state()["do"] != 0x0F:
                if time.monotonic() > deadline:
                    raise SystemExit("stall.sh: the run never drove the module")
                time.sleep(0.01)
            # Let the loop settle into its ticks, then freeze the runner.
            time.sleep(0.3)
            with open(f"/proc/{run.pid}/task/{run.pid}/children") as f:
                runner = int(f.read().split()[0])
            os.kill(runner, signal.SIGSTOP)
            t0 = time.monotonic()
            while state()["do"] != 0x00:
                if time.monotonic() - t0 > 20:
                    raise SystemExit("stall.sh: the module was not made safe within 20 s")
                time.sleep(0.002)
            took = time.monotonic() - t0
            err = run.communicate(timeout=20)[1]
            if run.returncode != 6 or "the scan loop stalled for" not in err:
                raise SystemExit(f"stall.sh: exit {run.returncode}, expected 6 and the stall:\n{err}")
            return took
        finally:
            if run.poll() is None:
                run.kill()
                run.wait()
    finally:
        sim.terminate()
        sim.wait()


times = []
for i in range(runs):
    with tempfile.TemporaryDirectory() as dir:
        t = one(dir)
    times.append(t)
    if os.environ.get("VERBOSE") == "1":
        print(f"run {i + 1}: {t:.3f} s")
times.sort()


def pct(p):
    # Nearest rank.
    k = max(0, min(len(times) - 1, int(-(-p * len(times) // 100)) - 1))
    return times[k]


print(f"stuck loop -> module read back safe, stall = {STALL:.1f} s, {runs} runs: "
      f"p50 {pct(50):.3f} s, p99 {pct(99):.3f} s, worst {times[-1]:.3f} s "
      f"(target: stall + 0.5 s = {STALL + 0.5:.1f} s)")
EOF
