//! `rigscript drive RIG ACTION`: acts on a running rig's simulated devices from a terminal
//! (press a switch, turn a knob, set an input, pulse a counter, fail a device), through its
//! control socket and the loop's control queue: the same actions as the scenario API, applied
//! between ticks. A demo or a manual commissioning check needs no browser.
//!
//! Exit statuses: 0 done; 1 refused (the message says why: a real device, a bad name); 2 usage;
//! 3 no such rig running.

use super::force::{point_shown, print_done};
use super::output::say;
use super::sim::parse_byte;
use super::status::find;
use crate::runtime::exit;
use crate::runtime::requests::{Drive, FieldAction};
use crate::runtime::snapshot::DeviceState;
use crate::service::control_client::Connection;
use crate::service::control_protocol::ClientRequest;
use clap::{Args, Subcommand, ValueEnum};

/// Options of `rigscript drive`.
#[derive(Debug, Args)]
pub struct DriveArgs {
    /// The rig (as `rigscript list` names it).
    pub rig: String,
    /// What to do.
    #[command(subcommand)]
    pub action: DriveAction,
}

/// On or off.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum OnOff {
    /// Energized.
    On,
    /// Released.
    Off,
}

/// The actions on a simulated device.
#[derive(Debug, Subcommand)]
pub enum DriveAction {
    /// Press a TRC1000 switch: `drive RIG press S12`
    Press {
        /// The switch (S1-S45 as the panel names them).
        switch: String,
        /// The panel, if the rig has more than one.
        #[arg(long)]
        device: Option<String>,
    },
    /// Release a TRC1000 switch
    Release {
        /// The switch.
        switch: String,
        /// The panel, if the rig has more than one.
        #[arg(long)]
        device: Option<String>,
    },
    /// Turn a TRC1000 rotary by half turns: `drive RIG turn S41A +4` (negative: back)
    Turn {
        /// The rotary (S41A ...).
        rotary: String,
        /// Half turns, signed.
        #[arg(allow_hyphen_values = true)]
        half_turns: i32,
        /// The panel, if the rig has more than one.
        #[arg(long)]
        device: Option<String>,
    },
    /// Set a TRP-C29U's energized inputs: `drive RIG set-inputs io 0x05`
    SetInputs {
        /// The module.
        device: String,
        /// The byte (bit n: DIn): 5, 0x05, 0b101.
        #[arg(value_parser = parse_byte)]
        value: u8,
    },
    /// Energize or release one TRP-C29U input: `drive RIG set-input io 3 on`
    SetInput {
        /// The module.
        device: String,
        /// The channel, 0-7.
        channel: u8,
        /// on or off.
        state: OnOff,
    },
    /// Give pulses to one TRP-C29U input: `drive RIG pulse io 2 10`
    Pulse {
        /// The module.
        device: String,
        /// The channel, 0-7.
        channel: u8,
        /// How many pulses.
        count: u32,
    },
    /// Make a simulated device stop answering (a pulled cable): `drive RIG fail io`
    Fail {
        /// The device.
        device: String,
    },
    /// Make it answer again
    Restore {
        /// The device.
        device: String,
    },
}

/// Runs `rigscript drive`.
pub fn run(args: DriveArgs) -> i32 {
    let mut c = match find(Some(&args.rig), None) {
        Ok(c) => c,
        Err(e) => return e.say("drive"),
    };
    // Switches and rotaries name no device: the rig's one panel, unless told.
    let panel = |given: Option<String>, c: &mut crate::service::control_client::Connection| {
        if let Some(d) = given {
            return Ok(d);
        }
        let snapshot = c.status().map_err(|e| e.to_string())?;
        let panels: Vec<&String> = snapshot
            .devices
            .iter()
            .filter(|(_, d)| matches!(d, DeviceState::Trc { .. }))
            .map(|(name, _)| name)
            .collect();
        match panels.as_slice() {
            [one] => Ok((*one).clone()),
            [] => Err("the rig has no TRC1000 panel".to_string()),
            _ => Err(format!(
                "the rig has several panels ({}): give --device NAME",
                panels
                    .iter()
                    .map(|s| s.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            )),
        }
    };
    let drive = match args.action {
        DriveAction::Press { switch, device } => panel(device, &mut c).map(|device| Drive {
            device,
            action: FieldAction::Press { name: switch },
        }),
        DriveAction::Release { switch, device } => panel(device, &mut c).map(|device| Drive {
            device,
            action: FieldAction::Release { name: switch },
        }),
        DriveAction::Turn {
            rotary,
            half_turns,
            device,
        } => panel(device, &mut c).map(|device| Drive {
            device,
            action: FieldAction::Turn {
                name: rotary,
                half_turns,
            },
        }),
        DriveAction::SetInputs { device, value } => Ok(Drive {
            device,
            action: FieldAction::SetInputs { value },
        }),
        DriveAction::SetInput {
            device,
            channel,
            state,
        } => Ok(Drive {
            device,
            action: FieldAction::SetInput {
                channel,
                on: state == OnOff::On,
            },
        }),
        DriveAction::Pulse {
            device,
            channel,
            count,
        } => Ok(Drive {
            device,
            action: FieldAction::Pulse { channel, count },
        }),
        DriveAction::Fail { device } => Ok(Drive {
            device,
            action: FieldAction::Fail,
        }),
        DriveAction::Restore { device } => Ok(Drive {
            device,
            action: FieldAction::Restore,
        }),
    };
    let drive = match drive {
        Ok(d) => d,
        Err(why) => {
            say(&format!("rigscript drive: {}: {why}", args.rig));
            return exit::ERROR;
        }
    };
    let done = done(&mut c, &drive);
    match c.ask(&ClientRequest::Drive(drive)) {
        Ok(_) => {
            print_done(&format!("{}: {done}", args.rig));
            exit::OK
        }
        Err(e) => {
            say(&format!("rigscript drive: {}: {e}", args.rig));
            exit::ERROR
        }
    }
}

/// What `drive` did, as a person reads it: `panel: S12 "cycle start" pressed`.
fn done(c: &mut Connection, drive: &Drive) -> String {
    let d = &drive.device;
    let mut point = |p: &str| point_shown(c, d, p);
    match &drive.action {
        FieldAction::Press { name } => format!("{d}: {} pressed", point(name)),
        FieldAction::Release { name } => format!("{d}: {} released", point(name)),
        FieldAction::Turn { name, half_turns } => {
            format!("{d}: {} turned {half_turns:+} half-turns", point(name))
        }
        FieldAction::SetInputs { value } => format!("{d}: inputs set to {value:#04x}"),
        FieldAction::SetInput { channel, on } => format!(
            "{d}: {} set {}",
            point(&format!("DI{channel}")),
            if *on { "on" } else { "off" }
        ),
        FieldAction::Pulse { channel, count } => format!(
            "{d}: {} pulsed {count} time{}",
            point(&format!("DI{channel}")),
            if *count == 1 { "" } else { "s" }
        ),
        FieldAction::Fail => format!("{d}: failed (it answers nothing until restored)"),
        FieldAction::Restore => format!("{d}: restored"),
    }
}
