//! What the runner tells the operator as it runs: one timestamped line per event handled,
//! output written, timer fired, script message, warning or error; to stderr, and kept in
//! memory for scenario tests.
//!
//! Writing never blocks a tick: each line is a `RunEvent::Log` on the run's event stream, and
//! the log's output is one consumer of it (`runtime::line_consumer`), on its own thread behind
//! a bounded queue. When stderr is not being read (a full pipe) and the queue is full, lines
//! are lost and counted; the log says how many before the next line it writes, and `--stats`
//! gives the total. Lines are text, or one JSON object a line (`--log-format json`: time, level,
//! source, message, device) for journald and Loki. A problem that repeats (a write the
//! module keeps refusing) is logged once and then counted (`repeating`).

use super::line_consumer::{LineConsumer, LineSink, Lines};
use super::observe::{Bound, EventKind, Events, Kinds, RunEvent};
use crate::time::clock::SharedClock;
use crate::time::duration::format_duration;
use crate::time::zone::Zone;
use chrono::{DateTime, Utc};
use std::collections::HashMap;
use std::io::Write;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Lines kept in memory at most (the oldest go first), so a long run cannot grow without bound.
pub const MAX_KEPT_LINES: usize = 10_000;

/// Log lines waiting for the output at most: their bytes, and their count; past either,
/// lines are lost and counted.
pub const QUEUE: Bound = Bound {
    events: 4096,
    bytes: 256 * 1024,
};

/// The longest line written, in bytes: longer ones are cut, saying how much was left out.
pub const MAX_LINE: usize = 4096;

/// How long closing the log waits for the writer to write what is queued (stderr may never
/// be read again).
pub const CLOSE_WAIT: Duration = Duration::from_secs(1);

/// The longest a repeating problem goes without a line (`Logger::repeating`).
pub const REPEAT_SUMMARY: Duration = Duration::from_secs(3600);

/// How much a line matters.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// What the script is doing (events, outputs, timers); left out with `--quiet`.
    Activity,
    /// The runner's notices (start-up, wake latency, stopping, stopped); left out with
    /// `--quiet`.
    Notice,
    /// The script's own `print` and `log`, the safe state the end wrote, and a problem
    /// settled.
    Info,
    /// Something the operator should look at.
    Warn,
    /// A failure.
    Error,
}

impl Level {
    /// The level's name in JSON lines, as syslog and journald name them.
    pub fn syslog_name(self) -> &'static str {
        match self {
            Level::Activity => "info",
            Level::Notice | Level::Info => "notice",
            Level::Warn => "warning",
            Level::Error => "error",
        }
    }
}

/// How lines are written.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum LogFormat {
    /// `12:00:00.020 io: outputs 0x00 -> 0x05 (top level)`.
    #[default]
    Text,
    /// One JSON object a line: time (RFC 3339), level (info, notice, warning, error), source
    /// (script or runner), message, device (the device it is about, or null).
    Json,
}

/// The runner's log.
pub struct Logger {
    clock: SharedClock,
    zone: Zone,
    quiet: bool,
    /// How the output writes lines, shared with its thread.
    style: Arc<Mutex<Style>>,
    writer: Option<LineConsumer>,
    /// Lines the writer dropped, once it is closed.
    dropped_before_close: u64,
    kept: Option<Vec<String>>,
    repeats: HashMap<String, Repeat>,
    events: Events,
}

/// How the log's output writes lines (set before the run, read by its thread).
#[derive(Default)]
struct Style {
    quiet: bool,
    format: LogFormat,
    devices: Vec<String>,
}

/// A problem being counted instead of logged.
struct Repeat {
    message: String,
    level: Level,
    since_line: u64,
    line_at: Duration,
}

impl Logger {
    /// A log stamped with `clock`'s wall time in `zone`, written to stderr if `to_stderr`.
    /// Its lines are events of its own stream (`events`, which the run shares).
    pub fn new(clock: SharedClock, zone: Zone, to_stderr: bool) -> Self {
        let mut log = Self {
            clock,
            zone,
            quiet: false,
            style: Arc::default(),
            writer: None,
            dropped_before_close: 0,
            kept: None,
            repeats: HashMap::new(),
            events: Events::default(),
        };
        if to_stderr {
            log.write_to(Box::new(std::io::stderr()));
        }
        log
    }

    /// Writes to `out` (instead of stderr), as a consumer of the log's events like stderr.
    pub fn with_output(clock: SharedClock, zone: Zone, out: impl Write + Send + 'static) -> Self {
        let mut log = Self::new(clock, zone, false);
        log.write_to(Box::new(out));
        log
    }

    /// Starts the output's consumer: the log's lines, written to `out` on a thread of its own.
    fn write_to(&mut self, out: Box<dyn Write + Send>) {
        let lines = OutputLines {
            style: Arc::clone(&self.style),
            zone: self.zone,
        };
        // The first consumer of a fresh stream: there is always room for it.
        if let Ok(subscription) =
            self.events
                .subscribe_to("log", QUEUE, Kinds::of(&[EventKind::Log]))
        {
            self.writer = Some(LineConsumer::spawn(
                "rigscript-log",
                subscription,
                lines,
                move || Some(LossyOutput(out)),
            ));
        }
    }

    /// Leaves out activity lines and the runner's notices (warnings, errors, script messages
    /// and the safe state still show).
    pub fn set_quiet(&mut self, quiet: bool) {
        self.quiet = quiet;
        crate::sync::lock(&self.style).quiet = quiet;
    }

    /// Writes lines as text or as JSON objects.
    pub fn set_format(&mut self, format: LogFormat) {
        crate::sync::lock(&self.style).format = format;
    }

    /// The rig's device names: a line that starts with one (`io: ...`) is about that device
    /// (the `device` field of JSON lines).
    pub fn set_devices(&mut self, names: impl IntoIterator<Item = String>) {
        crate::sync::lock(&self.style).devices = names.into_iter().collect();
    }

    /// Keeps lines in memory too (scenario tests read them back), always as text.
    pub fn keep_lines(&mut self) {
        if self.kept.is_none() {
            self.kept = Some(Vec::new());
        }
    }

    /// The lines kept so far (empty unless `keep_lines` was called).
    pub fn lines(&self) -> &[String] {
        self.kept.as_deref().unwrap_or(&[])
    }

    /// Lines lost so far because the output was not being read.
    pub fn dropped(&self) -> u64 {
        self.writer
            .as_ref()
            .map_or(self.dropped_before_close, |w| w.losses().count())
    }

    /// The run's event stream: every line is told to it (quiet or not: that is the log's
    /// output only), and the run shares it for everything else it tells.
    pub fn events(&self) -> &Events {
        &self.events
    }

    /// Writes one line at `level`: publishes it (the one place a line is told) and keeps it.
    pub fn line(&mut self, level: Level, message: &str) {
        let routine = matches!(level, Level::Activity | Level::Notice);
        let kept = self.kept.is_some() && !(routine && self.quiet);
        if !kept && !self.events.wants(EventKind::Log) {
            return;
        }
        let time = self.clock.wall();
        let shown = visible(message);
        let message = cut(&shown);
        self.events.publish(|| RunEvent::Log {
            level: level.syslog_name(),
            message: message.to_string(),
            time,
            routine,
        });
        if let (Some(lines), true) = (&mut self.kept, kept) {
            if lines.len() >= MAX_KEPT_LINES {
                lines.remove(0);
            }
            lines.push(text_line(
                &self.zone.at(time),
                level.syslog_name(),
                &message,
            ));
        }
    }

    /// An activity line.
    pub fn activity(&mut self, message: &str) {
        self.line(Level::Activity, message);
    }

    /// A notice of the runner.
    pub fn notice(&mut self, message: &str) {
        self.line(Level::Notice, message);
    }

    /// An information line.
    pub fn info(&mut self, message: &str) {
        self.line(Level::Info, message);
    }

    /// A warning line.
    pub fn warn(&mut self, message: &str) {
        self.line(Level::Warn, message);
    }

    /// An error line.
    pub fn error(&mut self, message: &str) {
        self.line(Level::Error, message);
    }

    /// A problem that may come back every tick (a write the module keeps refusing): logged
    /// the first time `key` reports it (or when its message changes), then only counted,
    /// with a line saying how often at most every `REPEAT_SUMMARY`, until `settled(key)`.
    pub fn repeating(&mut self, key: &str, level: Level, message: &str) {
        let now = self.clock.now();
        match self.repeats.get_mut(key) {
            Some(r) if r.message == message => {
                r.since_line = r.since_line.saturating_add(1);
                if now.saturating_sub(r.line_at) < REPEAT_SUMMARY {
                    return;
                }
                let line = format!(
                    "{message} (again {} times in the last {})",
                    r.since_line,
                    format_duration(Duration::from_secs(now.saturating_sub(r.line_at).as_secs()))
                );
                r.since_line = 0;
                r.line_at = now;
                self.line(level, &line);
            }
            _ => {
                self.repeats.insert(
                    key.to_string(),
                    Repeat {
                        message: message.to_string(),
                        level,
                        since_line: 0,
                        line_at: now,
                    },
                );
                self.line(level, message);
            }
        }
    }

    /// The problem under `key` is over: if it repeated since its last line, says how often,
    /// with `outcome` (`io: outputs written again`).
    pub fn settled(&mut self, key: &str, outcome: &str) {
        if let Some(r) = self.repeats.remove(key) {
            if r.since_line > 0 {
                let line = format!(
                    "{outcome} (the problem above came back {} more times)",
                    r.since_line
                );
                self.line(r.level.max_info(), &line);
            } else {
                self.line(Level::Info, outcome);
            }
        }
    }

    /// Writes what is queued, waiting at most `CLOSE_WAIT` for the output to take it; lines
    /// logged afterwards go nowhere but the kept lines and the stream's other consumers.
    pub fn close(&mut self) {
        if let Some(w) = self.writer.take() {
            let _ = w.close(CLOSE_WAIT);
            self.dropped_before_close = w.losses().count();
        }
    }
}

impl Level {
    fn max_info(self) -> Level {
        match self {
            Level::Activity => Level::Info,
            other => other,
        }
    }
}

impl Drop for Logger {
    fn drop(&mut self) {
        self.close();
    }
}

/// `message` with every control character written out (`\n`, `\r`, `\t`, `\x1b`, `\u{9b}`),
/// and the invisible characters that reorder or hide text (bidirectional controls), so no
/// text (a script's `log`, an error it threw, a retained MQTT message) can start a line that
/// looks like the runner's, move the cursor, recolour the terminal or set its title.
pub fn visible(message: &str) -> std::borrow::Cow<'_, str> {
    if !message.chars().any(hidden) {
        return message.into();
    }
    let mut out = String::with_capacity(message.len() + 8);
    for c in message.chars() {
        match c {
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if c.is_control() && u32::from(c) < 0x80 => {
                out.push_str(&format!("\\x{:02x}", u32::from(c)));
            }
            c if hidden(c) => out.push_str(&format!("\\u{{{:x}}}", u32::from(c))),
            c => out.push(c),
        }
    }
    out.into()
}

/// A control character, or one of Unicode's bidirectional controls (which reorder what a
/// terminal shows without showing themselves).
fn hidden(c: char) -> bool {
    c.is_control()
        || matches!(c, '\u{061c}' | '\u{200e}' | '\u{200f}' | '\u{202a}'..='\u{202e}' | '\u{2066}'..='\u{2069}')
}

/// `message` cut to `MAX_LINE` bytes (at a character boundary), saying how much was left out.
fn cut(message: &str) -> std::borrow::Cow<'_, str> {
    if message.len() <= MAX_LINE {
        return message.into();
    }
    let mut end = MAX_LINE;
    while !message.is_char_boundary(end) {
        end -= 1;
    }
    format!(
        "{}... ({} more bytes not shown)",
        &message[..end],
        message.len() - end
    )
    .into()
}

type Wall = chrono::DateTime<Zone>;

/// A line as text; `level` is the syslog name (`Level::syslog_name`).
fn text_line(wall: &Wall, level: &str, message: &str) -> String {
    let stamp = wall.format("%H:%M:%S%.3f");
    match level {
        "warning" => format!("{stamp} warning: {message}"),
        "error" => format!("{stamp} error: {message}"),
        _ => format!("{stamp} {message}"),
    }
}

/// A line as one JSON object; the source and device are read off the message's conventions
/// (`script: ...` from the script's `print`, `log` and `warn`; `NAME: ...` about a device).
fn json_line(wall: &Wall, level: &str, message: &str, devices: &[String]) -> String {
    let (source, device, text) = if let Some(rest) = message.strip_prefix("script: ") {
        ("script", None, rest)
    } else {
        let device = message.split_once(": ").and_then(|(head, rest)| {
            devices
                .iter()
                .find(|d| d.as_str() == head)
                .map(|d| (d.as_str(), rest))
        });
        match device {
            Some((d, rest)) => ("runner", Some(d), rest),
            None => ("runner", None, message),
        }
    };
    serde_json::json!({
        "time": wall.to_rfc3339_opts(chrono::SecondsFormat::Millis, false),
        "level": level,
        "source": source,
        "message": text,
        "device": device,
    })
    .to_string()
}

/// The log's output on its thread. A closed output must not stop the rig: what it refuses is
/// simply lost.
struct LossyOutput(Box<dyn Write + Send>);

impl LineSink for LossyOutput {
    fn write_batch(&mut self, batch: &str, _count: usize) {
        let _ = self
            .0
            .write_all(batch.as_bytes())
            .and_then(|()| self.0.flush());
    }
}

/// The log's lines as the output writes them: text or JSON, routine lines left out when
/// quiet, and a loss told before the line after it.
struct OutputLines {
    style: Arc<Mutex<Style>>,
    zone: Zone,
}

impl OutputLines {
    fn render(&self, time: DateTime<Utc>, level: &str, message: &str) -> String {
        let wall = self.zone.at(time);
        let style = crate::sync::lock(&self.style);
        match style.format {
            LogFormat::Text => text_line(&wall, level, message),
            LogFormat::Json => json_line(&wall, level, message, &style.devices),
        }
    }
}

impl Lines for OutputLines {
    fn line(&mut self, event: &RunEvent) -> Option<String> {
        let RunEvent::Log {
            level,
            message,
            time,
            routine,
        } = event
        else {
            return None;
        };
        if *routine && crate::sync::lock(&self.style).quiet {
            return None;
        }
        Some(self.render(*time, level, message))
    }

    fn lost(&mut self, lost: u64, next: &RunEvent) -> Option<String> {
        let RunEvent::Log { time, .. } = next else {
            return None;
        };
        Some(self.render(
            *time,
            Level::Warn.syslog_name(),
            &format!("{lost} log lines dropped: stderr not being read"),
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::time::clock::VirtualClock;
    use chrono::{TimeZone, Utc};
    use std::io::Read;
    use std::os::fd::{FromRawFd, OwnedFd};
    use std::sync::mpsc;
    use std::sync::Arc;

    fn clock() -> VirtualClock {
        let clock = VirtualClock::new(Utc.with_ymd_and_hms(2026, 3, 28, 12, 0, 1).unwrap());
        clock.advance(Duration::from_millis(20));
        clock
    }

    #[test]
    fn lines_carry_the_wall_time_in_the_zone_and_quiet_drops_activity_and_notices() {
        let mut log = Logger::new(
            Arc::new(clock()),
            Zone::parse("Europe/Amsterdam").unwrap(),
            false,
        );
        log.keep_lines();
        log.activity("io: outputs 0x00 -> 0x05");
        log.warn("late");
        log.set_quiet(true);
        log.activity("hidden");
        log.notice("stopped; exit status 0");
        log.info("script: mine");
        log.info("safe state (end of run): io outputs 0x00");
        log.error("broken");
        assert_eq!(
            log.lines(),
            [
                "13:00:01.020 io: outputs 0x00 -> 0x05",
                "13:00:01.020 warning: late",
                "13:00:01.020 script: mine",
                "13:00:01.020 safe state (end of run): io outputs 0x00",
                "13:00:01.020 error: broken"
            ]
        );
    }

    /// A pipe: (read end, write end).
    fn pipe() -> (std::fs::File, std::fs::File) {
        let mut fds = [0; 2];
        // SAFETY: `fds` has room for the two descriptors pipe() writes.
        assert_eq!(unsafe { libc::pipe(fds.as_mut_ptr()) }, 0);
        // SAFETY: both descriptors are fresh and owned by nothing else.
        unsafe {
            (
                std::fs::File::from(OwnedFd::from_raw_fd(fds[0])),
                std::fs::File::from(OwnedFd::from_raw_fd(fds[1])),
            )
        }
    }

    #[test]
    fn a_pipe_nobody_reads_never_blocks_the_logger_and_the_drops_are_told() {
        let (mut reader, writer) = pipe();
        let (done, finished) = mpsc::channel();
        let logging = std::thread::spawn(move || {
            let mut log = Logger::with_output(Arc::new(clock()), Zone::utc(), writer);
            // Far more than a pipe (64 KiB) and the queue (256 KiB) together hold.
            for n in 0..20_000 {
                log.info(&format!("line {n} {}", "x".repeat(100)));
            }
            done.send(log.dropped()).unwrap();
            log
        });
        // Nobody reads yet: the loop must still get through all of its lines.
        let dropped = finished
            .recv_timeout(Duration::from_secs(60))
            .expect("the logger blocked on a pipe nobody reads");
        assert!(dropped > 10_000, "{dropped} dropped");
        let mut log = logging.join().unwrap();
        // Someone reads again: the next line comes after a notice of what was lost.
        let reading = std::thread::spawn(move || {
            let mut all = String::new();
            let _ = reader.read_to_string(&mut all);
            all
        });
        std::thread::sleep(Duration::from_millis(200));
        log.info("after");
        log.close();
        drop(log);
        let text = reading.join().unwrap();
        // Each run of drops is told before the next line that got through: one run while the
        // writer was stuck, and, where the queue filled before the pipe did (a loaded
        // machine), one or more earlier ones. Together they tell every line dropped.
        let suffix = " log lines dropped: stderr not being read";
        let told: Vec<u64> = text
            .lines()
            .filter_map(|l| {
                l.split_once("warning: ")?
                    .1
                    .strip_suffix(suffix)?
                    .parse()
                    .ok()
            })
            .collect();
        assert_eq!(told.iter().sum::<u64>(), dropped, "told {told:?}");
        let last = text
            .rfind(suffix)
            .unwrap_or_else(|| panic!("no notice in {text:.500}"));
        assert!(text[last..].contains("after"), "the notice comes first");
        assert!(text.starts_with("12:00:01.020 line 0 "), "{:.100}", text);
    }

    #[test]
    fn json_lines_give_time_level_source_message_and_device() {
        let (mut reader, writer) = pipe();
        let mut log = Logger::with_output(Arc::new(clock()), Zone::utc(), writer);
        log.set_format(LogFormat::Json);
        log.set_devices(["io".to_string(), "panel".to_string()]);
        log.activity("io: outputs 0x00 -> 0x05 (top level)");
        log.info("script: hello \"there\"");
        log.error("in every 1s: boom");
        log.close();
        drop(log);
        let mut text = String::new();
        reader.read_to_string(&mut text).unwrap();
        let lines: Vec<serde_json::Value> = text
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        assert_eq!(
            lines,
            [
                serde_json::json!({"time": "2026-03-28T12:00:01.020+00:00", "level": "info",
                    "source": "runner", "message": "outputs 0x00 -> 0x05 (top level)",
                    "device": "io"}),
                serde_json::json!({"time": "2026-03-28T12:00:01.020+00:00", "level": "notice",
                    "source": "script", "message": "hello \"there\"", "device": null}),
                serde_json::json!({"time": "2026-03-28T12:00:01.020+00:00", "level": "error",
                    "source": "runner", "message": "in every 1s: boom", "device": null}),
            ]
        );
    }

    #[test]
    fn a_repeating_problem_is_logged_once_then_counted_and_summed_up() {
        let clock = clock();
        let mut log = Logger::new(Arc::new(clock.clone()), Zone::utc(), false);
        log.keep_lines();
        for _ in 0..50 {
            log.repeating(
                "io/write",
                Level::Error,
                "io: writing outputs failed: refused",
            );
            clock.advance(Duration::from_millis(20));
        }
        assert_eq!(log.lines().len(), 1);
        // An hour of it: one summary line.
        clock.advance(REPEAT_SUMMARY);
        log.repeating(
            "io/write",
            Level::Error,
            "io: writing outputs failed: refused",
        );
        log.repeating(
            "io/write",
            Level::Error,
            "io: writing outputs failed: other",
        );
        log.repeating(
            "io/write",
            Level::Error,
            "io: writing outputs failed: other",
        );
        log.settled("io/write", "io: outputs written again");
        log.settled("io/write", "said once only");
        let lines = log.lines().join("\n");
        assert_eq!(log.lines().len(), 4, "{lines}");
        assert!(
            lines.contains(
                "error: io: writing outputs failed: refused (again 50 times in the last 1h1s)"
            ),
            "{lines}"
        );
        assert!(
            lines.contains(
                "error: io: outputs written again (the problem above came back 1 more times)"
            ),
            "{lines}"
        );
    }

    #[test]
    fn control_characters_in_a_message_are_written_out_in_text_and_json() {
        let forged = "ready\n20:00:00.000 safe state (end of run): io outputs 0x00\r\x1b[2K\tdone\u{9b}\u{7f}";
        let shown = "ready\\n20:00:00.000 safe state (end of run): io outputs 0x00\\r\\x1b[2K\\tdone\\u{9b}\\x7f";
        for format in [LogFormat::Text, LogFormat::Json] {
            let (mut reader, writer) = pipe();
            let mut log = Logger::with_output(Arc::new(clock()), Zone::utc(), writer);
            log.keep_lines();
            log.set_format(format);
            log.info(&format!("script: {forged}"));
            log.warn(&format!("script: {forged}"));
            assert_eq!(log.lines()[0], format!("12:00:01.020 script: {shown}"));
            log.close();
            drop(log);
            let mut text = String::new();
            reader.read_to_string(&mut text).unwrap();
            assert_eq!(text.lines().count(), 2, "{format:?}: {text}");
            assert!(
                text.lines().all(|l| !l.chars().any(char::is_control)),
                "{format:?}: {text:?}"
            );
            if format == LogFormat::Json {
                let line: serde_json::Value =
                    serde_json::from_str(text.lines().next().unwrap()).unwrap();
                assert_eq!(line["message"], shown);
            } else {
                assert!(
                    text.contains(&format!("warning: script: {shown}")),
                    "{text}"
                );
            }
        }
    }

    #[test]
    fn long_lines_are_cut() {
        let mut log = Logger::new(Arc::new(clock()), Zone::utc(), false);
        log.keep_lines();
        log.info(&"é".repeat(5000));
        let line = &log.lines()[0];
        assert!(
            line.ends_with("... (5904 more bytes not shown)"),
            "{line:.80}"
        );
        assert!(line.len() < MAX_LINE + 100);
    }
}
