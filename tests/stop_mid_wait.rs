//! `rigscript run` stopped by SIGTERM while it waits for a module that went silent behind a
//! working serial device server (the TCP connection stays up): the wait is cut short at once,
//! the module gets its safe value as soon as it answers again, and the run ends with 143.

use crate::common::{rigscript, start_switchable_relay, SimProcess, TempDir};
use std::io::{BufRead, BufReader};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

/// What the module's retries cost before a stop could be seen without the cut: 6 tries of
/// 1 s, each after a settling second.
const RETRIES_TAKE: Duration = Duration::from_secs(11);

#[test]
fn a_sigterm_cuts_the_wait_for_a_silent_module_and_the_safe_value_is_written() {
    for protocol in ["modbus", "ascii"] {
        let mut sim = SimProcess::start(&["--protocol", protocol, "--id", "1"]);
        let silent = Arc::new(AtomicBool::new(false));
        let port = start_switchable_relay(&sim.path, Arc::clone(&silent));
        let dir = TempDir::new(&format!("stop-mid-wait-{protocol}"));
        let config = dir.file(
            "rig.toml",
            &format!(
                "period = \"20ms\"\n[devices.io]\nkind = \"trp-c29u\"\nport = \
                 \"tcp://127.0.0.1:{port}\"\nprotocol = \"{protocol}\"\nsafe_value = 0x05\n\
                 timeout = \"1s\"\nretries = 5\n"
            ),
        );
        let script = dir.file(
            "work.rhai",
            "io.outputs = 0xF0;\nevery(\"100ms\", || { let x = io.inputs; });\n",
        );
        let mut run = Command::new(rigscript())
            .args(["run", "--config", &config, &script])
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap();
        // The module answers again once the run says it is stopping: in time for the end's
        // write after a cut wait, too late for the retries of a wait that goes on.
        let (lines, log) = mpsc::channel();
        let stderr = BufReader::new(run.stderr.take().unwrap());
        let speak = Arc::clone(&silent);
        std::thread::spawn(move || {
            for line in stderr.lines().map_while(Result::ok) {
                if line.contains("stopping: SIGTERM received") {
                    speak.store(false, Ordering::SeqCst);
                }
                let _ = lines.send(line);
            }
        });
        let started = Instant::now();
        while sim.state()["do"] != 0xF0 && started.elapsed() < Duration::from_secs(20) {
            std::thread::sleep(Duration::from_millis(50));
        }
        assert_eq!(sim.state()["do"], 0xF0, "{protocol}: the script drives it");
        silent.store(true, Ordering::SeqCst);
        // Well into a read's first wait.
        std::thread::sleep(Duration::from_millis(400));
        let signalled = Instant::now();
        let ok = Command::new("kill")
            .args(["-TERM", &run.id().to_string()])
            .status()
            .unwrap()
            .success();
        assert!(ok);
        let status = run.wait().unwrap();
        let took = signalled.elapsed();
        let text = log.try_iter().collect::<Vec<_>>().join("\n");
        assert_eq!(status.code(), Some(143), "{protocol}: {text}");
        // A cut within 100 ms, the line's settling second, one exchange: about 1.2 s. Generous
        // for a loaded machine, and well under the retries a wait that goes on costs.
        assert!(
            took < RETRIES_TAKE / 2,
            "{protocol}: {took:?} from SIGTERM to exit\n{text}"
        );
        let state = sim.state();
        assert_eq!(
            state["do"], 0x05,
            "{protocol}: the safe value: {state}\n{text}"
        );
        assert!(
            text.contains("safe state (signal): io outputs 0x05"),
            "{protocol}: {text}"
        );
        assert!(
            !text.contains("lost"),
            "{protocol}: a cut is no loss: {text}"
        );
    }
}
