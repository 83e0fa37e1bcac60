//! `rigscript c29 monitor`: polls inputs, outputs and counters and prints each change as a line
//! until Ctrl-C.

use super::show::{byte_row, byte_table};
use super::CliError;
use crate::device::c29u::{C29u, C29uError, IoState};
use serde_json::{json, Value};
use std::io::Write;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

/// What the monitor compares between two polls.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct IoView {
    /// Outputs and inputs.
    pub io: IoState,
    /// The eight counters.
    pub counters: [u16; 8],
}

/// Something that changed between two polls.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum IoEvent {
    /// An input was energized (true) or released.
    Input { channel: u8, energized: bool },
    /// An output went on (true) or off.
    Output { channel: u8, on: bool },
    /// A counter changed.
    Counter { channel: u8, value: u16, was: u16 },
}

impl IoEvent {
    /// The event as words.
    pub fn text(&self) -> String {
        match *self {
            IoEvent::Input { channel, energized } => {
                format!(
                    "DI{channel} {}",
                    if energized { "energized" } else { "released" }
                )
            }
            IoEvent::Output { channel, on } => {
                format!("DO{channel} {}", if on { "on" } else { "off" })
            }
            IoEvent::Counter {
                channel,
                value,
                was,
            } => format!("counter DI{channel} {value} (was {was})"),
        }
    }

    /// The event as a JSON object.
    pub fn json(&self) -> Value {
        match *self {
            IoEvent::Input { channel, energized } => {
                json!({ "event": "input", "channel": channel, "energized": energized })
            }
            IoEvent::Output { channel, on } => {
                json!({ "event": "output", "channel": channel, "on": on })
            }
            IoEvent::Counter {
                channel,
                value,
                was,
            } => json!({ "event": "counter", "channel": channel, "value": value, "was": was }),
        }
    }
}

fn bit_changes(before: u8, after: u8) -> impl Iterator<Item = (u8, bool)> {
    (0u8..8)
        .filter(move |ch| (before ^ after) & (1 << ch) != 0)
        .map(move |ch| (ch, after & (1 << ch) != 0))
}

/// The changes from `before` to `after`: inputs, then outputs, then counters.
pub fn changes(before: &IoView, after: &IoView) -> Vec<IoEvent> {
    let mut events: Vec<IoEvent> = bit_changes(before.io.inputs, after.io.inputs)
        .map(|(channel, energized)| IoEvent::Input { channel, energized })
        .collect();
    events.extend(
        bit_changes(before.io.outputs, after.io.outputs)
            .map(|(channel, on)| IoEvent::Output { channel, on }),
    );
    events.extend(
        (0u8..)
            .zip(before.counters.iter().zip(after.counters.iter()))
            .filter(|(_, (was, value))| was != value)
            .map(|(channel, (&was, &value))| IoEvent::Counter {
                channel,
                value,
                was,
            }),
    );
    events
}

fn read_view(dev: &mut C29u) -> Result<IoView, C29uError> {
    Ok(IoView {
        io: dev.read_io()?,
        counters: dev.read_counters()?,
    })
}

fn view_text(view: &IoView) -> String {
    let counters: Vec<String> = view.counters.iter().map(u16::to_string).collect();
    format!(
        "{}counters {}",
        byte_table(&[
            byte_row("DI", view.io.inputs, "energized", "DI"),
            byte_row("DO", view.io.outputs, "on", "DO"),
        ]),
        counters.join(" ")
    )
}

fn now() -> chrono::DateTime<chrono::Local> {
    chrono::Local::now()
}

/// Polls `dev` every `interval` and prints what changed until `stop` is set. A missed answer
/// is a warning; a lost link ends the monitor with its error.
pub fn run(
    dev: &mut C29u,
    interval: Duration,
    json: bool,
    out: &mut dyn Write,
    stop: &AtomicBool,
) -> Result<(), CliError> {
    let mut last = read_view(dev)?;
    eprintln!("monitoring {}; Ctrl-C to stop", dev.describe());
    if json {
        writeln!(
            out,
            "{}",
            json!({
                "time": now().to_rfc3339(),
                "event": "state",
                "di": last.io.inputs,
                "do": last.io.outputs,
                "counters": last.counters,
            })
        )?;
    } else {
        writeln!(out, "{}", view_text(&last))?;
    }
    out.flush()?;
    while !stop.load(Ordering::Relaxed) {
        std::thread::sleep(interval);
        let view = match read_view(dev) {
            Ok(view) => view,
            Err(e @ C29uError::Timeout { .. }) | Err(e @ C29uError::Garbled { .. }) => {
                eprintln!("warning: {e}");
                continue;
            }
            Err(e) => return Err(e.into()),
        };
        let time = now();
        for event in changes(&last, &view) {
            if json {
                let mut line = event.json();
                line["time"] = json!(time.to_rfc3339());
                writeln!(out, "{line}")?;
            } else {
                writeln!(out, "{} {}", time.format("%H:%M:%S%.3f"), event.text())?;
            }
        }
        out.flush()?;
        last = view;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn view(inputs: u8, outputs: u8, counters: [u16; 8]) -> IoView {
        IoView {
            io: IoState {
                outputs,
                inputs,
                inputs_raw: !inputs,
            },
            counters,
        }
    }

    #[test]
    fn no_change_no_event() {
        let v = view(0x05, 0x21, [1; 8]);
        assert!(changes(&v, &v).is_empty());
    }

    #[test]
    fn inputs_then_outputs_then_counters_each_channel_once() {
        let before = view(0b0000_0101, 0x00, [0, 0, 0, 12, 0, 0, 0, 0]);
        let after = view(0b1000_0001, 0x20, [0, 0, 0, 15, 0, 0, 0, 0]);
        let text: Vec<String> = changes(&before, &after).iter().map(IoEvent::text).collect();
        assert_eq!(
            text,
            vec![
                "DI2 released",
                "DI7 energized",
                "DO5 on",
                "counter DI3 15 (was 12)"
            ]
        );
        assert_eq!(
            changes(&before, &after)[3].json(),
            json!({ "event": "counter", "channel": 3, "value": 15, "was": 12 })
        );
    }

    #[test]
    fn a_cleared_counter_is_a_change_too() {
        let events = changes(&view(0, 0, [9; 8]), &view(0, 0, [9, 0, 9, 9, 9, 9, 9, 9]));
        assert_eq!(
            events,
            vec![IoEvent::Counter {
                channel: 1,
                value: 0,
                was: 9
            }]
        );
    }
}
