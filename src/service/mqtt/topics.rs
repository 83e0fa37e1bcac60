//! The rig's topics on the broker and what goes on them (pure: names and payloads, no I/O).

use crate::runtime::observe::RunEvent;
pub use crate::runtime::topic_filter::{check_topic, MAX_PAYLOAD, MAX_TOPIC};
use serde_json::{json, Value};

/// The retained status message while the rig is connected.
pub const ONLINE: &str = "online";

/// The retained status message after it is gone (its last will, or a normal stop).
pub const OFFLINE: &str = "offline";

/// The rig's topics, from its prefix.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Topics {
    prefix: String,
}

impl Topics {
    /// Topics under `prefix` with `{rig}` standing for `rig`.
    pub fn new(prefix: &str, rig: &str) -> Self {
        Self {
            prefix: prefix.replace("{rig}", rig),
        }
    }

    /// The prefix as used.
    pub fn prefix(&self) -> &str {
        &self.prefix
    }

    /// `{prefix}/status`: `online`, or `offline` (retained).
    pub fn status(&self) -> String {
        format!("{}/status", self.prefix)
    }

    /// `{prefix}/state/{device}` (retained).
    pub fn state(&self, device: &str) -> String {
        format!("{}/state/{device}", self.prefix)
    }

    /// `{prefix}/records` (QoS 1).
    pub fn records(&self) -> String {
        format!("{}/records", self.prefix)
    }

    /// `{prefix}/last_record`: the last record the broker acknowledged (retained, at most
    /// once a second), for a dashboard that shows the rig's latest.
    pub fn last_record(&self) -> String {
        format!("{}/last_record", self.prefix)
    }

    /// `{prefix}/log`: warnings, errors, safe-state events.
    pub fn log(&self) -> String {
        format!("{}/log", self.prefix)
    }

    /// `{prefix}/cmd/+`: the commands the rig listens to.
    pub fn commands(&self) -> String {
        format!("{}/cmd/+", self.prefix)
    }

    /// The command named by an inbound topic, if it is one of ours (`{prefix}/cmd/NAME`).
    pub fn command_name<'t>(&self, topic: &'t str) -> Option<&'t str> {
        let name = topic
            .strip_prefix(self.prefix.as_str())?
            .strip_prefix("/cmd/")?;
        (!name.is_empty() && !name.contains('/')).then_some(name)
    }

    /// `{prefix}/cmd/{name}/reply`.
    pub fn reply(&self, name: &str) -> String {
        format!("{}/cmd/{name}/reply", self.prefix)
    }
}

/// What of an event goes to `{prefix}/log`, as its JSON payload: warnings and errors, the
/// safe state, devices lost and back, script failures and the end.
pub fn log_payload(event: &RunEvent, time: &str) -> Option<String> {
    let v = match event {
        RunEvent::Log { level, message, .. } => {
            let safe = message.contains("safe state") || message.contains("safe value");
            if !(matches!(*level, "warning" | "error") || safe) {
                return None;
            }
            json!({"time": time, "level": level, "message": message})
        }
        RunEvent::DeviceLost { device, cause } => {
            json!({"time": time, "level": "warning", "event": "device_lost",
                   "device": device, "message": cause})
        }
        RunEvent::DeviceBack { device } => {
            json!({"time": time, "level": "info", "event": "device_back", "device": device})
        }
        RunEvent::ScriptFailed { message } => {
            json!({"time": time, "level": "error", "event": "script_failed", "message": message})
        }
        RunEvent::Ended {
            status,
            reason,
            safe,
            unconfirmed,
        } => json!({"time": time, "level": if unconfirmed.is_empty() { "info" } else { "error" },
                    "event": "ended", "status": status, "message": reason,
                    "safe": safe, "unconfirmed": unconfirmed}),
        _ => return None,
    };
    Some(v.to_string())
}

/// A command's reply: `{"ok":true,"value":V}` or `{"ok":false,"error":"..."}`.
pub fn reply_payload(result: &Result<Value, String>) -> String {
    match result {
        Ok(value) => json!({"ok": true, "value": value}),
        Err(error) => json!({"ok": false, "error": error}),
    }
    .to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::topic_filter::{check_filter, filter_matches};

    #[test]
    fn topics_come_from_the_prefix_and_commands_are_told_by_name() {
        let t = Topics::new("rigscript/{rig}", "host-bench");
        assert_eq!(t.status(), "rigscript/host-bench/status");
        assert_eq!(t.state("io"), "rigscript/host-bench/state/io");
        assert_eq!(t.command_name("rigscript/host-bench/cmd/arm"), Some("arm"));
        assert_eq!(t.command_name("rigscript/host-bench/cmd/arm/reply"), None);
        assert_eq!(t.command_name("rigscript/other/cmd/arm"), None);
        assert_eq!(t.reply("arm"), "rigscript/host-bench/cmd/arm/reply");
    }

    #[test]
    fn filters_match_as_mqtt_says() {
        assert!(filter_matches("rigscript/+/status", "rigscript/b2/status"));
        assert!(filter_matches("rigscript/#", "rigscript/b2/state/io"));
        assert!(!filter_matches(
            "rigscript/+/status",
            "rigscript/b2/state/io"
        ));
        assert!(!filter_matches("a/b", "a/b/c"));
        assert!(check_filter("a/+/#").is_ok());
        assert!(check_filter("a/#/b").is_err());
        assert!(check_filter("a/b+").is_err());
        assert!(check_topic("a/+").is_err());
    }

    #[test]
    fn only_what_matters_goes_to_the_log_topic() {
        let info = RunEvent::Log {
            level: "info",
            message: "hello".into(),
            time: chrono::DateTime::UNIX_EPOCH,
            routine: true,
        };
        assert_eq!(log_payload(&info, "t"), None);
        let warn = RunEvent::Log {
            level: "warning",
            message: "io: late".into(),
            time: chrono::DateTime::UNIX_EPOCH,
            routine: false,
        };
        let v: Value = serde_json::from_str(&log_payload(&warn, "t").unwrap()).unwrap();
        assert_eq!(v["level"], "warning");
        assert_eq!(
            reply_payload(&Err("no handler".into())),
            r#"{"error":"no handler","ok":false}"#
        );
    }
}
