//! The page's memory of the last minutes (`GET /api/history`), so a reload keeps its plots
//! and log: a thread that follows the event stream and keeps each change of a device's
//! inputs, outputs (a panel's relay), counters and rotaries, the last log lines and records,
//! in bounded rings
//! (`MAX_POINTS`, `MAX_LINES`, `MAX_RECORDS`; the oldest go first).

use crate::protocol::trc1000::Rotary;
use crate::runtime::observe::{Events, Reading, RunEvent, DEFAULT_QUEUE};
use crate::sync::lock;
use serde::Serialize;
use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, SystemTime, UNIX_EPOCH};

/// Changes kept at most (of every device's every series together).
pub const MAX_POINTS: usize = 6_000;

/// Log lines kept at most.
pub const MAX_LINES: usize = 200;

/// Records and measurements kept at most.
pub const MAX_RECORDS: usize = 100;

/// One change of one series.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Point {
    /// When it was seen, in milliseconds since the Unix epoch.
    pub t: u64,
    /// The device's name in the rig.
    pub device: String,
    /// `inputs`, `outputs` (a TRC1000's relay), `counter0` ... `counter7`, or a rotary's
    /// name (`S41A`).
    pub series: String,
    /// The new value.
    pub value: u32,
}

/// One log line as the page shows it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Line {
    /// When it was seen, in milliseconds since the Unix epoch.
    pub t: u64,
    /// Its level.
    pub level: &'static str,
    /// The message.
    pub message: String,
}

/// What `/api/history` answers.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct Kept {
    /// The changes, oldest first.
    pub points: VecDeque<Point>,
    /// The log lines, oldest first.
    pub log: VecDeque<Line>,
    /// The records file's last lines (records and measurements, with `pass`), oldest first.
    pub records: VecDeque<serde_json::Value>,
    /// Events this history lost (its queue was full): the plots have gaps.
    pub dropped: u64,
}

impl Kept {
    /// Takes in `event`, seen at `t` (ms since the epoch).
    pub fn take(&mut self, t: u64, event: &RunEvent) {
        match event {
            RunEvent::Inputs { device, reading } | RunEvent::Shown { device, reading } => match reading {
                Reading::DigitalInputs { value } => {
                    self.point(t, device, "inputs".into(), u32::from(*value));
                }
                Reading::Counters { values } => {
                    for (n, v) in values.iter().enumerate() {
                        self.point(t, device, format!("counter{n}"), u32::from(*v));
                    }
                }
                Reading::Rotaries { values } => {
                    for (r, v) in Rotary::ALL.iter().zip(values) {
                        self.point(t, device, r.name().into(), u32::from(*v));
                    }
                }
                Reading::Switches { .. } => {}
            },
            RunEvent::Outputs { device, value, .. } => {
                self.point(t, device, "outputs".into(), u32::from(*value));
            }
            RunEvent::Log { level, message, .. } => {
                if self.log.len() >= MAX_LINES {
                    self.log.pop_front();
                }
                self.log.push_back(Line {
                    t,
                    level,
                    message: message.clone(),
                });
            }
            RunEvent::Record { line } => {
                if self.records.len() >= MAX_RECORDS {
                    self.records.pop_front();
                }
                if let Ok(v) = serde_json::from_str(line) {
                    self.records.push_back(v);
                }
            }
            _ => {}
        }
    }

    fn point(&mut self, t: u64, device: &str, series: String, value: u32) {
        // A reading that repeats the series' last value adds nothing to a step plot.
        let last = self
            .points
            .iter()
            .rev()
            .find(|p| p.device == device && p.series == series);
        if last.is_some_and(|p| p.value == value) {
            return;
        }
        if self.points.len() >= MAX_POINTS {
            self.points.pop_front();
        }
        self.points.push_back(Point {
            t,
            device: device.to_string(),
            series,
            value,
        });
    }
}

/// The history and the thread that keeps it.
pub struct History {
    kept: Arc<Mutex<Kept>>,
    stop: Arc<AtomicBool>,
}

impl History {
    /// Follows `events` from now on (an empty history if the stream takes no more consumers).
    pub fn follow(events: &Events) -> Self {
        let kept = Arc::new(Mutex::new(Kept::default()));
        let stop = Arc::new(AtomicBool::new(false));
        if let Ok(mut sub) = events.subscribe("web history", DEFAULT_QUEUE) {
            let (k, s) = (Arc::clone(&kept), Arc::clone(&stop));
            let _ = std::thread::Builder::new()
                .name("web history".into())
                .spawn(move || {
                    while !s.load(Ordering::SeqCst) {
                        let next = sub.next(Duration::from_millis(200));
                        let lost = sub.newly_dropped();
                        let mut kept = lock(&k);
                        kept.dropped += lost;
                        match next {
                            Ok(event) => kept.take(now_ms(), &event),
                            Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
                            Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => return,
                        }
                    }
                });
        }
        Self { kept, stop }
    }

    /// What is kept, as JSON.
    pub fn json(&self) -> Vec<u8> {
        serde_json::to_vec(&*lock(&self.kept)).unwrap_or_default()
    }

    /// Lets the thread go (at its next slice).
    pub fn stop(&self) {
        self.stop.store(true, Ordering::SeqCst);
    }
}

/// Milliseconds since the Unix epoch (the page plots wall-clock time).
pub fn now_ms() -> u64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, crate::runtime::snapshot::millis)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn outputs(value: u8) -> RunEvent {
        RunEvent::Outputs {
            device: "io".into(),
            value,
            cause: "t".into(),
        }
    }

    #[test]
    fn changes_are_kept_repeats_are_not_and_the_oldest_go_first() {
        let mut k = Kept::default();
        k.take(1, &outputs(1));
        k.take(2, &outputs(1));
        k.take(3, &outputs(2));
        assert_eq!(k.points.len(), 2);
        for n in 0..MAX_POINTS * 2 {
            k.take(10 + n as u64, &outputs((n % 2) as u8));
        }
        assert_eq!(k.points.len(), MAX_POINTS);
        assert!(k.points.front().unwrap().t > 3);
        for n in 0..MAX_LINES + 5 {
            k.take(
                n as u64,
                &RunEvent::Log {
                    level: "info",
                    message: n.to_string(),
                    time: chrono::Utc::now(),
                    routine: false,
                },
            );
        }
        assert_eq!(k.log.len(), MAX_LINES);
        assert_eq!(k.log.front().unwrap().message, "5");
    }

    #[test]
    fn counters_are_a_series_each() {
        let mut k = Kept::default();
        let reading = Reading::Counters {
            values: [0, 1, 2, 3, 4, 5, 6, 7],
        };
        k.take(
            1,
            &RunEvent::Inputs {
                device: "io".into(),
                reading,
            },
        );
        assert_eq!(k.points.len(), 8);
        assert_eq!(k.points[7].series, "counter7");
        assert_eq!(k.points[7].value, 7);
    }

    #[test]
    fn rotaries_are_a_series_each_by_name_and_only_their_changes_are_kept() {
        let mut k = Kept::default();
        let mut values = [0u8; 14];
        for at in [1, 2] {
            k.take(
                at,
                &RunEvent::Inputs {
                    device: "panel".into(),
                    reading: Reading::Rotaries { values },
                },
            );
        }
        assert_eq!(k.points.len(), 14, "the same reading again adds nothing");
        values[3] = 3;
        k.take(
            3,
            &RunEvent::Inputs {
                device: "panel".into(),
                reading: Reading::Rotaries { values },
            },
        );
        let last = k.points.back().unwrap();
        assert_eq!((last.series.as_str(), last.value, last.t), ("S42B", 3, 3));
    }
}
