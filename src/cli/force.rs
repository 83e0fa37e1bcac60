//! `rigscript force RIG DEVICE.POINT on|off|BYTE --for DUR` and `rigscript unforce RIG
//! DEVICE.POINT`: an operator holds an output or an input of a running rig at a value for a
//! while (commissioning), through its control socket, where its rig.toml says `force = true`
//! (`runtime::forcing`). The run logs and records it; the safe state wins over it.
//!
//! Exit statuses: 0 done; 1 refused (the message says why: forcing off, held safe, a bad
//! point); 2 usage; 3 no such rig running.

use super::output::say;
use super::sim::parse_byte;
use super::status::find;
use crate::runtime::exit;
use crate::runtime::forcing::{parse_for, ForceOrder, ForceValue};
use crate::runtime::snapshot::DeviceState;
use crate::service::control_client::Connection;
use crate::service::control_protocol::ClientRequest;
use clap::Args;

/// Options of `rigscript force`.
#[derive(Debug, Args)]
pub struct ForceArgs {
    /// The rig (as `rigscript list` names it).
    pub rig: String,
    /// DEVICE.POINT: io.DO3, io.DI0, io.outputs, io.inputs, panel.relay, panel.S12.
    pub point: String,
    /// on or off for a channel or a switch; a byte (5, 0x05, 0b101) for outputs, inputs or
    /// the relay.
    #[arg(value_parser = parse_value)]
    pub value: ForceValue,
    /// How long the force holds ("30s", "5m"; at most 8h): it expires then.
    #[arg(long = "for", value_name = "DUR", value_parser = check_for)]
    pub duration: String,
    /// Takes the force even though it breaks the invariant NAME (as the script names it):
    /// logged and recorded with it, and shown as overridden until the force ends. Repeat for
    /// more than one.
    #[arg(long = "override", value_name = "INVARIANT")]
    pub overrides: Vec<String>,
}

/// Options of `rigscript unforce`.
#[derive(Debug, Args)]
pub struct UnforceArgs {
    /// The rig (as `rigscript list` names it).
    pub rig: String,
    /// The point forced (io.DO3 ...).
    pub point: String,
}

/// `on`, `off` or a byte.
fn parse_value(text: &str) -> Result<ForceValue, String> {
    match text.trim().to_ascii_lowercase().as_str() {
        "on" | "true" => Ok(ForceValue::On(true)),
        "off" | "false" => Ok(ForceValue::On(false)),
        _ => parse_byte(text)
            .map(ForceValue::Byte)
            .map_err(|e| format!("{e}; or on, off")),
    }
}

/// A duration a force may hold for, kept as given.
fn check_for(text: &str) -> Result<String, String> {
    parse_for(text)
        .map(|_| text.to_string())
        .map_err(|e| e.to_string())
}

/// Runs `rigscript force`.
pub fn force(args: ForceArgs) -> i32 {
    let overriding: Vec<String> = args.overrides.iter().map(|o| format!("{o:?}")).collect();
    let mut done = format!("forced {} for {}", args.value.text(), args.duration.trim());
    if !overriding.is_empty() {
        done.push_str(&format!(
            ", overriding the invariant {}",
            overriding.join(", ")
        ));
    }
    let order = ForceOrder {
        point: args.point.clone(),
        value: args.value,
        duration: args.duration,
        overrides: args.overrides,
    };
    ask(
        &args.rig,
        "force",
        &ClientRequest::Force(order),
        &args.point,
        &done,
    )
}

/// Runs `rigscript unforce`.
pub fn unforce(args: UnforceArgs) -> i32 {
    let request = ClientRequest::Unforce {
        point: args.point.clone(),
    };
    ask(
        &args.rig,
        "unforce",
        &request,
        &args.point,
        "unforced: the script's value applies again",
    )
}

/// Asks the rig `rig` for `request` on `point`; done, prints what was `done` to it
/// (`bench: io.DO0 "motor" forced on for 5m`).
fn ask(rig: &str, command: &str, request: &ClientRequest, point: &str, done: &str) -> i32 {
    let mut c = match find(Some(rig), None) {
        Ok(c) => c,
        Err(e) => return e.say(command),
    };
    match c.ask(request) {
        Ok(_) => {
            let (device, on_device) = point.split_once('.').unwrap_or((point, ""));
            let shown = format!("{device}.{}", point_shown(&mut c, device, on_device));
            print_done(&format!("{rig}: {shown} {done}"));
            exit::OK
        }
        Err(e) => {
            say(&format!("rigscript {command}: {rig}: {e}"));
            exit::ERROR
        }
    }
}

/// `point` of `device` as a person reads it, with the name rig.toml gives it
/// (`DO0 "motor"`), asked of the rig; as given when the rig does not say.
pub(super) fn point_shown(c: &mut Connection, device: &str, point: &str) -> String {
    let upper = point.to_ascii_uppercase();
    let name = c.status().ok().and_then(|s| {
        let names = match s.devices.get(device)? {
            DeviceState::C29u { names, .. } | DeviceState::Trc { names, .. } => names.clone(),
        };
        names.get(point).or_else(|| names.get(&upper)).cloned()
    });
    match name {
        Some(name) => format!("{point} \"{name}\""),
        None => point.to_string(),
    }
}

/// Tells on standard output what a command did; a closed standard output loses the line.
pub(super) fn print_done(line: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stdout(), "{line}");
}
