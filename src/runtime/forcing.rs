//! Forcing for commissioning: an operator holds an output or an input of a device at a value
//! for a while (`rigscript force`, `POST /api/force`), allowed only where rig.toml says
//! `force = true`. A forced output is written instead of what the script commands; a forced
//! input is what the script reads. Every force expires on the run's clock, and every one is
//! logged and recorded when it is set, changed, removed, expired or cancelled.
//!
//! The safe state always wins: a force is cancelled (and none is taken) whenever the outputs
//! go to their safe state (held safe for a lost device, a script error, the end of the run),
//! and the safe-state writes use rig.toml's safe values, never a forced one. So outputs only
//! ever hold the safe value, a value the script commanded, or an operator's logged, expiring
//! force.

use super::devices::Device;
use super::snapshot::millis;
use super::state::Runtime;
use crate::protocol::trc1000::{Switch, SwitchSet};
use crate::time::duration::{format_duration, parse_duration};
use serde::{Deserialize, Serialize};
use serde_json::json;
use std::time::Duration;

/// Forces held at once at most; one more is refused.
pub const MAX_FORCES: usize = 32;

/// The longest a force may be asked to hold (a commissioning shift).
pub const MAX_FOR: Duration = Duration::from_secs(8 * 3600);

/// A force asked for: `{"point":"io.DO3","value":true,"for":"5m"}`.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ForceOrder {
    /// `DEVICE.POINT`: `io.DO3`, `io.DI0`, `io.outputs`, `io.inputs`, `panel.relay`,
    /// `panel.S12`.
    pub point: String,
    /// `true`/`false` for one channel or switch, a byte for `outputs`/`inputs`, 0-7 for
    /// `relay`.
    pub value: ForceValue,
    /// How long it holds (`"5m"`), at most `MAX_FOR`.
    #[serde(rename = "for")]
    pub duration: String,
    /// The invariants the person accepts this force breaking (`--override NAME`): without
    /// one, a force of outputs that would make an invariant false is refused.
    #[serde(default, rename = "override", skip_serializing_if = "Vec::is_empty")]
    pub overrides: Vec<String>,
}

/// The value a point is forced to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ForceValue {
    /// On or off (a channel, a switch).
    On(bool),
    /// A byte (a DO or DI byte, a relay position).
    Byte(u8),
}

impl ForceValue {
    /// As people write it: `on`, `off`, `0x05`.
    pub fn text(self) -> String {
        match self {
            ForceValue::On(true) => "on".into(),
            ForceValue::On(false) => "off".into(),
            ForceValue::Byte(b) => format!("{b:#04x}"),
        }
    }
}

/// What a force acts on, resolved against the rig's devices.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Target {
    /// Bits of a TRP-C29U's DO byte: `mask` held at `bits`.
    Outputs { mask: u8, bits: u8 },
    /// Bits of a TRP-C29U's DI byte as the script reads it.
    Inputs { mask: u8, bits: u8 },
    /// A TRC1000's relay position.
    Relay(u8),
    /// A TRC1000 switch as the script reads it.
    Switch { switch: Switch, pressed: bool },
}

/// One force held.
#[derive(Debug, Clone)]
struct Force {
    /// `DEVICE.POINT` as the rig names it (`io.DO3`).
    point: String,
    /// The device's index.
    device: usize,
    target: Target,
    value: ForceValue,
    /// How long it was asked to hold.
    held_for: Duration,
    /// When it ends, on the run's monotonic clock.
    until: Duration,
    /// Who asked.
    by: String,
    /// The invariants it was allowed to break (`ForceOrder::overrides`).
    overrides: Vec<String>,
}

impl Force {
    /// Whether it changes what is written (outputs, relay) rather than what the script reads.
    fn acts_on_outputs(&self) -> bool {
        matches!(self.target, Target::Outputs { .. } | Target::Relay(_))
    }
}

/// The forces of a run.
#[derive(Debug, Default)]
pub struct Forces {
    /// Whether rig.toml allows forcing (`force = true`).
    allowed: bool,
    held: Vec<Force>,
    /// The invariants are being judged on what would be written: the script's reads of its
    /// outputs and relay give them with the forces over them (`runner::force::judge`).
    judging: bool,
}

/// A force taken but not yet told: the loop judges it against the invariants, then confirms
/// it (logged and recorded) or withdraws it (what it replaced is back).
#[derive(Debug)]
pub struct StagedForce {
    point: String,
    /// The force it replaced, if it changed one.
    replaced: Option<Force>,
}

impl StagedForce {
    /// The point it forces (`io.DO3`).
    pub fn point(&self) -> &str {
        &self.point
    }
}

/// A force as the snapshot shows it (`rigscript status`, `/api/state`).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ForceShown {
    /// `DEVICE.POINT`.
    pub point: String,
    /// The value it is held at.
    pub value: ForceValue,
    /// Milliseconds until it expires.
    pub remaining_ms: u64,
    /// Who set it.
    pub by: String,
    /// The invariants it was allowed to break.
    #[serde(default)]
    pub overrides: Vec<String>,
}

/// Why a force or an unforce was refused; `Display` is the message for people.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum ForceError {
    /// rig.toml does not say `force = true`.
    #[error(
        "forcing is off for this rig: add `force = true` to its rig.toml to allow forcing \
         outputs and inputs (for commissioning)"
    )]
    NotAllowed,
    /// The outputs are held at their safe state, which wins over any force.
    #[error("{0}: the safe state wins over a force")]
    Safe(String),
    /// No such device in the rig.
    #[error("the rig has no device called {device} (devices: {known})")]
    NoDevice {
        /// The name given.
        device: String,
        /// The rig's devices.
        known: String,
    },
    /// The device has no such point.
    #[error("{0}")]
    NoPoint(String),
    /// The value or the duration does not fit.
    #[error("{0}")]
    Bad(String),
    /// `MAX_FORCES` are held.
    #[error("{MAX_FORCES} points are forced already: unforce one first")]
    Full,
    /// `unforce` of a point that is not forced.
    #[error("{0} is not forced")]
    NotForced(String),
}

impl ForceError {
    /// The HTTP status it is answered with.
    pub fn status(&self) -> u16 {
        match self {
            ForceError::NotAllowed => 403,
            ForceError::NoDevice { .. } | ForceError::NoPoint(_) | ForceError::NotForced(_) => 404,
            ForceError::Bad(_) => 400,
            ForceError::Safe(_) | ForceError::Full => 409,
        }
    }
}

/// A device's kind, as far as its points go.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A TRP-C29U: DO0-DO7, DI0-DI7, outputs, inputs.
    C29u,
    /// A TRC1000: relay, S1-S45.
    Trc,
}

impl Kind {
    fn of(d: &Device) -> Self {
        match d {
            Device::C29u(_) => Kind::C29u,
            Device::Trc(_) => Kind::Trc,
        }
    }
}

/// How long a force is asked to hold (`"5m"`): above zero, at most `MAX_FOR`.
pub fn parse_for(text: &str) -> Result<Duration, ForceError> {
    let d =
        parse_duration(text.trim()).map_err(|e| ForceError::Bad(format!("for {text:?}: {e}")))?;
    if d.is_zero() || d > MAX_FOR {
        return Err(ForceError::Bad(format!(
            "a force holds for more than 0 and at most {} (asked: {text})",
            format_duration(MAX_FOR)
        )));
    }
    Ok(d)
}

/// Checks `DEVICE.POINT` and its value against the rig's devices (`kinds`, by name): the
/// point as shown (`io.DO3`) and what it acts on. The page checks an order with it before
/// asking the loop, which checks it again.
pub fn check_point(
    point: &str,
    value: ForceValue,
    kinds: &[(&str, Kind)],
) -> Result<String, ForceError> {
    resolve(point, value, kinds).map(|(shown, _)| shown)
}

fn resolve(
    point: &str,
    value: ForceValue,
    kinds: &[(&str, Kind)],
) -> Result<(String, Target), ForceError> {
    let Some((device, name)) = point.split_once('.') else {
        return Err(ForceError::NoPoint(format!(
            "{point:?} is not DEVICE.POINT (io.DO3, io.DI0, io.outputs, io.inputs, \
             panel.relay, panel.S12)"
        )));
    };
    let Some(&(_, kind)) = kinds.iter().find(|(n, _)| *n == device) else {
        let known: Vec<&str> = kinds.iter().map(|(n, _)| *n).collect();
        return Err(ForceError::NoDevice {
            device: device.to_string(),
            known: known.join(", "),
        });
    };
    let bad = |why: &str| ForceError::Bad(format!("{point}: {why}"));
    let on = |v: ForceValue| match v {
        ForceValue::On(on) => Ok(on),
        ForceValue::Byte(b @ (0 | 1)) => Ok(b == 1),
        ForceValue::Byte(_) => Err(bad("a channel or switch is forced on or off")),
    };
    let byte = |v: ForceValue| match v {
        ForceValue::Byte(b) => Ok(b),
        ForceValue::On(_) => Err(bad("a whole byte is forced to a number (0x05)")),
    };
    let bit = |ch: u8, v: ForceValue| on(v).map(|on| (1u8 << ch, if on { 1u8 << ch } else { 0 }));
    let upper = name.to_ascii_uppercase();
    let target = match kind {
        Kind::C29u => {
            if let Some(ch) = channel_of(&upper, "DO") {
                let (mask, bits) = bit(ch, value)?;
                Target::Outputs { mask, bits }
            } else if let Some(ch) = channel_of(&upper, "DI") {
                let (mask, bits) = bit(ch, value)?;
                Target::Inputs { mask, bits }
            } else if name == "outputs" {
                Target::Outputs {
                    mask: 0xFF,
                    bits: byte(value)?,
                }
            } else if name == "inputs" {
                Target::Inputs {
                    mask: 0xFF,
                    bits: byte(value)?,
                }
            } else {
                return Err(ForceError::NoPoint(format!(
                    "{point}: a TRP-C29U's points are DO0-DO7, DI0-DI7, outputs and inputs"
                )));
            }
        }
        Kind::Trc => {
            if name == "relay" {
                let r = byte(value)?;
                if r > 7 {
                    return Err(bad("the relay is 0-7"));
                }
                Target::Relay(r)
            } else if let Some(switch) = Switch::from_name(&upper) {
                Target::Switch {
                    switch,
                    pressed: on(value)?,
                }
            } else {
                return Err(ForceError::NoPoint(format!(
                    "{point}: a TRC1000's points are relay and its switches (S1-S45)"
                )));
            }
        }
    };
    let shown = match target {
        Target::Outputs { mask: 0xFF, .. } => format!("{device}.outputs"),
        Target::Inputs { mask: 0xFF, .. } => format!("{device}.inputs"),
        Target::Outputs { mask, .. } => format!("{device}.DO{}", mask.trailing_zeros()),
        Target::Inputs { mask, .. } => format!("{device}.DI{}", mask.trailing_zeros()),
        Target::Relay(_) => format!("{device}.relay"),
        Target::Switch { switch, .. } => format!("{device}.{}", switch.name()),
    };
    Ok((shown, target))
}

impl Forces {
    /// Whether forcing is allowed.
    pub fn allowed(&self) -> bool {
        self.allowed
    }

    /// Whether the invariants are being judged on what would be written.
    #[inline]
    pub fn judging(&self) -> bool {
        self.judging
    }

    /// Judges the invariants on what would be written (`true`) or on what the script wants.
    pub fn set_judging(&mut self, on: bool) {
        self.judging = on;
    }

    /// Whether a force changes what is written (an output or a relay): only then can the
    /// outputs differ from what the script wants, and need judging.
    #[inline]
    pub fn hold_outputs(&self) -> bool {
        self.held.iter().any(Force::acts_on_outputs)
    }

    /// Whether a force held was allowed to break the invariant `name`.
    pub fn overridden(&self, name: &str) -> bool {
        self.held.iter().any(|f| f.overrides.iter().any(|o| o == name))
    }

    /// The DO byte to write for the device at `idx` when the script commands `script`.
    pub fn outputs(&self, idx: usize, script: u8) -> u8 {
        self.held
            .iter()
            .filter(|f| f.device == idx)
            .fold(script, |v, f| match f.target {
                Target::Outputs { mask, bits } => (v & !mask) | (bits & mask),
                _ => v,
            })
    }

    /// The relay to select on the device at `idx` when the script commands `script`.
    pub fn relay(&self, idx: usize, script: u8) -> u8 {
        self.held
            .iter()
            .filter(|f| f.device == idx)
            .fold(script, |v, f| match f.target {
                Target::Relay(r) => r,
                _ => v,
            })
    }

    /// The DI byte the script reads from the device at `idx` when the module reads `read`.
    pub fn inputs(&self, idx: usize, read: u8) -> u8 {
        self.held
            .iter()
            .filter(|f| f.device == idx)
            .fold(read, |v, f| match f.target {
                Target::Inputs { mask, bits } => (v & !mask) | (bits & mask),
                _ => v,
            })
    }

    /// The switches the script reads from the device at `idx` when the board reads `read`.
    pub fn switches(&self, idx: usize, read: SwitchSet) -> SwitchSet {
        self.held
            .iter()
            .filter(|f| f.device == idx)
            .fold(read, |mut v, f| {
                if let Target::Switch { switch, pressed } = f.target {
                    v.set(switch, pressed);
                }
                v
            })
    }

    /// Whether any input of the device at `idx` is forced (its reading is changed).
    fn forces_inputs(&self, idx: usize) -> bool {
        self.held.iter().any(|f| {
            f.device == idx && matches!(f.target, Target::Inputs { .. } | Target::Switch { .. })
        })
    }
}

impl<H: Clone> Runtime<H> {
    /// Allows forcing for this run (rig.toml's `force = true`).
    pub fn allow_forcing(&mut self, allowed: bool) {
        self.forces.allowed = allowed;
    }

    /// Sets or changes a force asked by `by`, logged and recorded; the outputs are written by
    /// the caller (between ticks, or at the tick's end). The loop judges it first
    /// (`stage_force`, then `confirm_force` or `withdraw_force`).
    pub fn force(&mut self, order: &ForceOrder, by: &str) -> Result<(), ForceError> {
        let staged = self.stage_force(order, by)?;
        self.confirm_force(staged);
        Ok(())
    }

    /// Takes a force asked by `by` without telling it yet: confirmed or withdrawn next.
    pub fn stage_force(&mut self, order: &ForceOrder, by: &str) -> Result<StagedForce, ForceError> {
        if !self.forces.allowed {
            return Err(ForceError::NotAllowed);
        }
        if self.safety.held() {
            return Err(ForceError::Safe(
                "every output is held at its safe state (a device was lost past its grace time)"
                    .into(),
            ));
        }
        let held_for = parse_for(&order.duration)?;
        let kinds: Vec<(&str, Kind)> = self
            .devices
            .iter()
            .map(|d| (d.name(), Kind::of(d)))
            .collect();
        let (point, target) = resolve(&order.point, order.value, &kinds)?;
        let device = order
            .point
            .split_once('.')
            .and_then(|(name, _)| kinds.iter().position(|(n, _)| *n == name))
            .unwrap_or(0);
        let until = self.now().saturating_add(held_for);
        let existing = self.forces.held.iter().position(|f| f.point == point);
        if existing.is_none() && self.forces.held.len() >= MAX_FORCES {
            return Err(ForceError::Full);
        }
        let force = Force {
            point: point.clone(),
            device,
            target,
            value: order.value,
            held_for,
            until,
            by: by.to_string(),
            overrides: order.overrides.clone(),
        };
        // The newest force goes last: a force that breaks an invariant later ends first.
        let replaced = existing.map(|i| self.forces.held.remove(i));
        self.forces.held.push(force);
        Ok(StagedForce { point, replaced })
    }

    /// Tells a staged force (logged, recorded, with the invariants it may break) and lets the
    /// script read it.
    pub fn confirm_force(&mut self, staged: StagedForce) {
        let Some(f) = self.forces.held.iter().find(|f| f.point == staged.point) else {
            return;
        };
        let (device, point, value, held_for) = (f.device, f.point.clone(), f.value, f.held_for);
        let (by, overrides) = (f.by.clone(), f.overrides.clone());
        let (event, verb) = match staged.replaced {
            Some(_) => ("changed", "changed to"),
            None => ("set", "forced"),
        };
        let shown = self.point_shown(device, &point);
        let breaking = if overrides.is_empty() {
            String::new()
        } else {
            format!(
                ", overriding the invariant {}",
                overrides
                    .iter()
                    .map(|o| format!("{o:?}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            )
        };
        self.log_mut().warn(&format!(
            "force: {shown} {verb} {} for {} (by {by}){breaking}",
            value.text(),
            format_duration(held_for)
        ));
        let mut taken = json!({ "value": value, "for_ms": millis(held_for) });
        if !overrides.is_empty() {
            taken["overrides"] = json!(overrides);
        }
        self.record_force(device, &point, event, &by, taken);
        self.reread_forced(device);
    }

    /// Takes a staged force back untold: the force it replaced, if any, holds again.
    pub fn withdraw_force(&mut self, staged: StagedForce) {
        self.forces.held.retain(|f| f.point != staged.point);
        if let Some(f) = staged.replaced {
            self.forces.held.push(f);
        }
    }

    /// Ends the newest force of outputs or relay not allowed to break `invariant`, because
    /// with it the outputs would make that invariant (stated at `at`) false; false if none.
    pub fn end_force_breaking(&mut self, invariant: &str, at: Option<&str>) -> bool {
        let Some(i) = self
            .forces
            .held
            .iter()
            .rposition(|f| f.acts_on_outputs() && !f.overrides.iter().any(|o| o == invariant))
        else {
            return false;
        };
        let f = self.forces.held.remove(i);
        let shown = self.point_shown(f.device, &f.point);
        let place = at.map(|a| format!(" ({a})")).unwrap_or_default();
        self.log_mut().warn(&format!(
            "force: {shown} ended: with it the outputs would break the invariant \
             {invariant:?}{place}; the script's value applies again"
        ));
        let breaks = json!({ "breaks": invariant });
        self.record_force(f.device, &f.point, "ended", "invariant", breaks);
        self.ended(&f, "ended");
        true
    }

    /// Ends the force on `point`, asked by `by`.
    pub fn unforce(&mut self, point: &str, by: &str) -> Result<(), ForceError> {
        if !self.forces.allowed {
            return Err(ForceError::NotAllowed);
        }
        let Some(i) = self.forces.held.iter().position(|f| f.point == point) else {
            return Err(ForceError::NotForced(point.to_string()));
        };
        let f = self.forces.held.remove(i);
        let shown = self.point_shown(f.device, &f.point);
        self.log_mut().warn(&format!(
            "force: {shown} removed (by {by}): the script's value applies again"
        ));
        self.record_force(f.device, &f.point, "removed", by, json!({}));
        self.ended(&f, "removed");
        Ok(())
    }

    /// Ends every force whose time is over; true if one ended.
    pub fn expire_forces(&mut self) -> bool {
        let now = self.now();
        let (over, kept): (Vec<Force>, Vec<Force>) = std::mem::take(&mut self.forces.held)
            .into_iter()
            .partition(|f| now >= f.until);
        self.forces.held = kept;
        for f in &over {
            let shown = self.point_shown(f.device, &f.point);
            self.log_mut().warn(&format!(
                "force: {shown} expired after {}: the script's value applies again",
                format_duration(f.held_for)
            ));
            self.record_force(f.device, &f.point, "expired", "expiry", json!({}));
            self.ended(f, "expired");
        }
        !over.is_empty()
    }

    /// Cancels every force because the outputs go to their safe state (`why`).
    pub fn cancel_forces(&mut self, why: &str) {
        for f in std::mem::take(&mut self.forces.held) {
            let shown = self.point_shown(f.device, &f.point);
            self.log_mut().warn(&format!(
                "force: {shown} cancelled: the safe state wins ({why})"
            ));
            self.record_force(f.device, &f.point, "cancelled", why, json!({}));
            self.reread_forced(f.device);
        }
    }

    /// When the next force expires, if one is held.
    pub fn next_force_expiry(&self) -> Option<Duration> {
        self.forces.held.iter().map(|f| f.until).min()
    }

    /// The forces held, for the snapshot.
    pub fn forces_shown(&self) -> Vec<ForceShown> {
        let now = self.now();
        self.forces
            .held
            .iter()
            .map(|f| ForceShown {
                point: f.point.clone(),
                value: f.value,
                remaining_ms: millis(f.until.saturating_sub(now)),
                by: f.by.clone(),
                overrides: f.overrides.clone(),
            })
            .collect()
    }

    /// A forced input applies from the next reading, not the one the tick already made.
    fn reread_forced(&mut self, idx: usize) {
        match self.devices.get_mut(idx) {
            Some(Device::C29u(d)) => d.reread_inputs(),
            Some(Device::Trc(d)) => d.reread_switches(),
            None => {}
        }
    }

    /// Names a force's end (`force on io.DO3 expired`) as the cause of the write that puts
    /// the script's value back, which would otherwise give the script's last cause.
    fn ended(&mut self, f: &Force, how: &str) {
        let cause = format!("force on {} {how}", f.point);
        match (self.devices.get_mut(f.device), f.target) {
            (Some(Device::C29u(d)), Target::Outputs { .. }) => d.credit_outputs_to(cause),
            (Some(Device::Trc(d)), Target::Relay(_)) => d.credit_relay_to(cause),
            _ => {}
        }
        self.reread_forced(f.device);
    }

    /// The name rig.toml gives `point` (`io.DO0`) of the device at `device`, if any.
    fn point_name(&self, device: usize, point: &str) -> Option<String> {
        let (_, on_device) = point.split_once('.')?;
        let names = self.devices.get(device)?.names();
        names.name_of(on_device).map(str::to_string)
    }

    /// `point` as a person reads it: `io.DO0 "motor"`, or `io.DO0` without a name.
    fn point_shown(&self, device: usize, point: &str) -> String {
        match self.point_name(device, point) {
            Some(name) => format!("{point} \"{name}\""),
            None => point.to_string(),
        }
    }

    /// One record line of a force's life (`{"name":"force","value":{...}}`): the point, with
    /// its name (`point_name`) when rig.toml gives it one, the event, who, and `details` (an
    /// object: the value and `for_ms` of a force taken, `overrides`, `breaks`).
    fn record_force(
        &mut self,
        device: usize,
        point: &str,
        event: &str,
        by: &str,
        details: serde_json::Value,
    ) {
        let mut v = json!({ "point": point, "event": event, "by": by });
        if let Some(name) = self.point_name(device, point) {
            v["point_name"] = json!(name);
        }
        if let serde_json::Value::Object(details) = details {
            for (key, value) in details {
                v[key] = value;
            }
        }
        self.record("force", v);
    }
}

/// The channel of `DO3` / `DI3` (0-7), in upper case.
fn channel_of(upper: &str, prefix: &str) -> Option<u8> {
    let n: u8 = upper.strip_prefix(prefix)?.parse().ok()?;
    (n < 8).then_some(n)
}

impl<H: Clone> Runtime<H> {
    /// Applies the forced inputs to the reading of the device at `idx` just made.
    pub(super) fn force_readings(&mut self, idx: usize) {
        if !self.forces.forces_inputs(idx) {
            return;
        }
        let forces = &self.forces;
        match self.devices.get_mut(idx) {
            Some(Device::C29u(d)) => d.force_inputs(|v| forces.inputs(idx, v)),
            Some(Device::Trc(d)) => d.force_switches(|v| forces.switches(idx, v)),
            None => {}
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::trc1000::Switch;
    use crate::runtime::testing::{TestRig, IO, PANEL};

    fn order(point: &str, value: ForceValue, duration: &str) -> ForceOrder {
        ForceOrder {
            overrides: Vec::new(),
            point: point.into(),
            value,
            duration: duration.into(),
        }
    }

    fn forcing() -> TestRig {
        let mut r = TestRig::started();
        r.rt.allow_forcing(true);
        r
    }

    fn records(r: &TestRig) -> Vec<serde_json::Value> {
        r.rt.records_kept()
            .iter()
            .filter(|v| v["name"] == "force")
            .map(|v| v["value"].clone())
            .collect()
    }

    #[test]
    fn a_forced_output_is_written_over_the_scripts_and_expires_on_the_runs_clock() {
        let mut r = forcing();
        r.rt.set_outputs(IO, 0x21);
        r.rt.flush_outputs();
        r.rt.force(&order("io.DO3", ForceValue::On(true), "5s"), "tester")
            .unwrap();
        assert!(r.rt.outputs_pending(), "the force waits to be written");
        r.rt.flush_outputs();
        assert_eq!(
            r.sim.outputs("io").unwrap(),
            0x29,
            "DO3 on, the rest the script's"
        );
        let log = r.log();
        assert!(
            log.contains("force: io.DO3 forced on for 5s (by tester)"),
            "{log}"
        );
        assert!(log.contains("io: outputs 0x21 -> 0x29 (forced)"), "{log}");
        // The script's commands go on under the force.
        r.rt.set_outputs(IO, 0x00);
        r.rt.flush_outputs();
        assert_eq!(r.sim.outputs("io").unwrap(), 0x08);
        assert_eq!(r.rt.forces_shown()[0].remaining_ms, 5000);
        r.clock.advance(Duration::from_millis(4999));
        assert!(!r.rt.expire_forces(), "not over yet");
        r.clock.advance(Duration::from_millis(1));
        assert_eq!(r.rt.next_force_expiry(), Some(r.rt.now()));
        assert!(r.rt.expire_forces());
        r.rt.flush_outputs();
        assert_eq!(
            r.sim.outputs("io").unwrap(),
            0x00,
            "the script's value again"
        );
        assert!(r.rt.forces_shown().is_empty());
        let log = r.log();
        assert!(
            log.contains("force: io.DO3 expired after 5s: the script's value applies again"),
            "{log}"
        );
        let kept = records(&r);
        assert_eq!(kept[0]["event"], "set");
        assert_eq!(kept[0]["point"], "io.DO3");
        assert_eq!(kept[0]["value"], true);
        assert_eq!(kept[0]["for_ms"], 5000);
        assert_eq!(kept[1]["event"], "expired");
    }

    #[test]
    fn a_force_set_again_is_a_change_and_unforce_ends_it() {
        let mut r = forcing();
        r.rt.force(&order("io.outputs", ForceValue::Byte(0xF0), "1m"), "a")
            .unwrap();
        r.rt.force(&order("io.outputs", ForceValue::Byte(0x0F), "2m"), "b")
            .unwrap();
        assert_eq!(r.rt.forces_shown().len(), 1);
        r.rt.flush_outputs();
        assert_eq!(r.sim.outputs("io").unwrap(), 0x0F);
        assert!(r
            .log()
            .contains("force: io.outputs changed to 0x0f for 2m (by b)"));
        assert_eq!(
            r.rt.unforce("io.DO1", "c"),
            Err(ForceError::NotForced("io.DO1".into()))
        );
        r.rt.unforce("io.outputs", "c").unwrap();
        r.rt.flush_outputs();
        assert_eq!(
            r.sim.outputs("io").unwrap(),
            0x05,
            "the script's (the safe value)"
        );
        let log = r.log();
        assert!(
            log.contains("io: outputs 0x0f -> 0x05 (force on io.outputs removed)"),
            "the write the removal makes says so: {log}"
        );
        let events: Vec<_> = records(&r).iter().map(|v| v["event"].clone()).collect();
        assert_eq!(events, ["set", "changed", "removed"]);
    }

    #[test]
    fn a_forced_input_is_what_the_script_reads_until_the_force_ends() {
        let mut r = forcing();
        r.sim.set_inputs("io", 0x01).unwrap();
        r.next_tick(Duration::from_millis(100));
        assert_eq!(r.rt.inputs(IO), 0x01);
        r.rt.force(&order("io.DI3", ForceValue::On(true), "1s"), "t")
            .unwrap();
        r.rt.force(&order("panel.S12", ForceValue::On(true), "1s"), "t")
            .unwrap();
        assert_eq!(r.rt.inputs(IO), 0x09, "the forced reading at once");
        r.next_tick(Duration::from_millis(100));
        assert_eq!(r.rt.inputs(IO), 0x09);
        let s12 = Switch::from_name("S12").unwrap();
        assert!(r.rt.switches(PANEL).is_pressed(s12));
        r.next_tick(Duration::from_millis(900));
        assert!(r.rt.expire_forces());
        assert_eq!(r.rt.inputs(IO), 0x01, "the module's reading again");
        assert!(!r.rt.switches(PANEL).is_pressed(s12));
    }

    #[test]
    fn the_safe_state_cancels_every_force_and_none_is_taken_while_held() {
        let mut r = forcing();
        r.rt.force(&order("io.outputs", ForceValue::Byte(0xFF), "1h"), "t")
            .unwrap();
        r.rt.force(&order("panel.relay", ForceValue::Byte(6), "1h"), "t")
            .unwrap();
        r.rt.flush_outputs();
        assert_eq!(r.sim.outputs("io").unwrap(), 0xFF);
        assert_eq!(r.sim.relay("panel").unwrap(), 6);
        r.rt.write_safe_state("script error");
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
        assert!(r.rt.forces_shown().is_empty());
        assert!(r
            .log()
            .contains("force: io.outputs cancelled: the safe state wins (script error)"));
        r.rt.flush_outputs();
        assert_eq!(
            r.sim.outputs("io").unwrap(),
            0x05,
            "nothing forced comes back"
        );
        // A device lost past its grace time holds everything safe: a force goes with it.
        r.rt.force(&order("io.DO7", ForceValue::On(true), "1h"), "t")
            .unwrap();
        r.rt.flush_outputs();
        assert_eq!(r.sim.outputs("io").unwrap(), 0x85);
        r.sim.set_gone("panel", true).unwrap();
        r.next_tick(Duration::from_millis(10));
        r.rt.switches(PANEL);
        assert!(!r.rt.devices.online(PANEL));
        r.clock.advance(Duration::from_millis(1500));
        r.rt.supervise();
        assert!(r.rt.held_safe());
        r.rt.flush_outputs();
        assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
        assert!(r.rt.forces_shown().is_empty());
        let e =
            r.rt.force(&order("io.DO7", ForceValue::On(true), "1h"), "t")
                .unwrap_err();
        assert!(matches!(e, ForceError::Safe(_)), "{e}");
        assert_eq!(e.status(), 409);
    }

    #[test]
    fn forcing_is_refused_unless_allowed_and_bad_orders_say_why() {
        let mut r = TestRig::started();
        let e =
            r.rt.force(&order("io.DO3", ForceValue::On(true), "5m"), "t")
                .unwrap_err();
        assert_eq!(e, ForceError::NotAllowed);
        assert!(e.to_string().contains("force = true"), "{e}");
        assert_eq!(e.status(), 403);
        r.rt.allow_forcing(true);
        let refused = |r: &mut TestRig, point: &str, value: ForceValue, d: &str| {
            r.rt.force(&order(point, value, d), "t").unwrap_err()
        };
        let on = ForceValue::On(true);
        assert_eq!(refused(&mut r, "pump.DO3", on, "5m").status(), 404);
        assert_eq!(refused(&mut r, "io.DO8", on, "5m").status(), 404);
        assert_eq!(refused(&mut r, "io", on, "5m").status(), 404);
        assert_eq!(refused(&mut r, "panel.S99", on, "5m").status(), 404);
        assert_eq!(
            refused(&mut r, "io.DO3", ForceValue::Byte(7), "5m").status(),
            400
        );
        assert_eq!(refused(&mut r, "io.outputs", on, "5m").status(), 400);
        assert_eq!(
            refused(&mut r, "panel.relay", ForceValue::Byte(8), "5m").status(),
            400
        );
        assert_eq!(refused(&mut r, "io.DO3", on, "0s").status(), 400);
        assert_eq!(refused(&mut r, "io.DO3", on, "9h").status(), 400);
        assert_eq!(refused(&mut r, "io.DO3", on, "300").status(), 400);
        assert!(r.rt.forces_shown().is_empty());
        assert!(records(&r).is_empty(), "a refusal is no force");
        // Lower case is read, the rig's own spelling shown.
        r.rt.force(&order("io.do2", ForceValue::Byte(1), "5m"), "t")
            .unwrap();
        assert_eq!(r.rt.forces_shown()[0].point, "io.DO2");
    }

    #[test]
    fn forces_are_bounded() {
        let mut r = forcing();
        for ch in 0..8 {
            for kind in ["DO", "DI"] {
                r.rt.force(
                    &order(&format!("io.{kind}{ch}"), ForceValue::On(true), "1m"),
                    "t",
                )
                .unwrap();
            }
        }
        for n in 1..=MAX_FORCES - 16 {
            r.rt.force(
                &order(&format!("panel.S{n}"), ForceValue::On(true), "1m"),
                "t",
            )
            .unwrap();
        }
        let e =
            r.rt.force(&order("panel.relay", ForceValue::Byte(1), "1m"), "t")
                .unwrap_err();
        assert_eq!(e, ForceError::Full);
        r.rt.force(&order("io.DO0", ForceValue::On(false), "1m"), "t")
            .expect("a change of a held force is no new one");
    }
}
