//! TRC1000 board model: relay selector, 45 switches, 14 half-turn counters, answering packets.

use crate::link::far_end::PacketDevice;
use crate::protocol::trc1000::{
    Command, Packet, Relay, Response, Rotary, RotaryValues, Switch, SwitchSet,
};

/// A name that is not a switch or rotary of the board.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum Trc1000SimError {
    /// Not one of S1..S45.
    #[error("no switch called {0:?} on the TRC1000 (S1..S45)")]
    UnknownSwitch(String),
    /// Not one of the 14 rotary names.
    #[error("no rotary called {0:?} on the TRC1000 (S37-S40, S41A/B..S45A/B)")]
    UnknownRotary(String),
}

/// The simulated board: what a user does to the panel and what the PC has selected.
#[derive(Debug, Clone, Default)]
pub struct Trc1000Sim {
    relay: Relay,
    switches: SwitchSet,
    rotaries: RotaryValues,
    relay_commands: usize,
}

impl Trc1000Sim {
    /// A board at power-on: relay 0, nothing pressed, all counters zero.
    pub fn new() -> Self {
        Self::default()
    }

    /// Presses the switch called `name` (held until released).
    pub fn press(&mut self, name: &str) -> Result<(), Trc1000SimError> {
        let s = switch(name)?;
        self.switches.set(s, true);
        Ok(())
    }

    /// Releases the switch called `name`.
    pub fn release(&mut self, name: &str) -> Result<(), Trc1000SimError> {
        let s = switch(name)?;
        self.switches.set(s, false);
        Ok(())
    }

    /// Sets a switch by type.
    pub fn set_switch(&mut self, switch: Switch, pressed: bool) {
        self.switches.set(switch, pressed);
    }

    /// Turns the rotary called `name` by `half_turns` (negative = the other way); its 8-bit
    /// counter wraps at 256 like the board's.
    pub fn turn(&mut self, name: &str, half_turns: i32) -> Result<(), Trc1000SimError> {
        let r =
            Rotary::from_name(name).ok_or_else(|| Trc1000SimError::UnknownRotary(name.into()))?;
        self.turn_rotary(r, half_turns);
        Ok(())
    }

    /// Turns a rotary by type.
    pub fn turn_rotary(&mut self, rotary: Rotary, half_turns: i32) {
        // rem_euclid(256) is in 0..=255, so the cast keeps the value.
        let step = half_turns.rem_euclid(256) as u8;
        let now = self.rotaries.get(rotary);
        self.rotaries.set(rotary, now.wrapping_add(step));
    }

    /// The relay last selected by the PC (0 at power-on).
    pub fn relay(&self) -> Relay {
        self.relay
    }

    /// How many relay-select commands arrived (to tell "selected 0" from "never selected").
    pub fn relay_commands(&self) -> usize {
        self.relay_commands
    }

    /// The switch states as the board would report them.
    pub fn switches(&self) -> SwitchSet {
        self.switches
    }

    /// The rotary counters as the board would report them.
    pub fn rotaries(&self) -> RotaryValues {
        self.rotaries
    }

    /// The counter of the rotary called `name`.
    pub fn rotary(&self, name: &str) -> Result<u8, Trc1000SimError> {
        let r =
            Rotary::from_name(name).ok_or_else(|| Trc1000SimError::UnknownRotary(name.into()))?;
        Ok(self.rotaries.get(r))
    }
}

fn switch(name: &str) -> Result<Switch, Trc1000SimError> {
    Switch::from_name(name).ok_or_else(|| Trc1000SimError::UnknownSwitch(name.into()))
}

impl PacketDevice for Trc1000Sim {
    fn receive(&mut self, packet: &Packet) -> Option<Packet> {
        // Unknown commands are ignored by the board: no answer at all.
        let response = match Command::decode(packet).ok()? {
            Command::SelectRelay(relay) => {
                self.relay = relay;
                self.relay_commands = self.relay_commands.saturating_add(1);
                return None;
            }
            Command::RequestInput => Response::Inputs(self.switches),
            Command::RequestRotary0 => Response::Rotary0(self.rotaries.rotary0()),
            Command::RequestRotary1 => Response::Rotary1(self.rotaries.rotary1()),
        };
        Some(response.encode())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ask(sim: &mut Trc1000Sim, cmd: Command) -> Option<Packet> {
        sim.receive(&cmd.encode())
    }

    #[test]
    fn pressed_switches_show_in_the_c1_answer_at_their_bits() {
        let mut sim = Trc1000Sim::new();
        sim.press("S3").unwrap();
        sim.press("s41").unwrap();
        sim.press("S27").unwrap();
        // S3 = b0 bit 2, S41 = b4 bit 0, S27 = b5 bit 1.
        assert_eq!(
            ask(&mut sim, Command::RequestInput),
            Some([0xC1, 0x04, 0, 0, 0, 0x01, 0x02, 0])
        );
        sim.release("S41").unwrap();
        assert_eq!(
            ask(&mut sim, Command::RequestInput),
            Some([0xC1, 0x04, 0, 0, 0, 0, 0x02, 0])
        );
    }

    #[test]
    fn unknown_names_are_errors_and_change_nothing() {
        let mut sim = Trc1000Sim::new();
        assert_eq!(
            sim.press("S46"),
            Err(Trc1000SimError::UnknownSwitch("S46".into()))
        );
        assert_eq!(
            sim.turn("S41", 2),
            Err(Trc1000SimError::UnknownRotary("S41".into()))
        );
        assert_eq!(sim.switches(), SwitchSet::new());
        assert_eq!(sim.rotaries(), RotaryValues::default());
    }

    #[test]
    fn turns_count_half_turns_and_wrap_at_256_both_ways() {
        let mut sim = Trc1000Sim::new();
        sim.turn("S41A", 3).unwrap();
        sim.turn("S40", -2).unwrap();
        assert_eq!(sim.rotary("S41A").unwrap(), 3);
        assert_eq!(sim.rotary("S40").unwrap(), 0xFE);
        sim.turn("S40", 4).unwrap();
        assert_eq!(sim.rotary("S40").unwrap(), 2);
        sim.turn("S41A", 256 * 3 + 1).unwrap();
        assert_eq!(sim.rotary("S41A").unwrap(), 4);
        sim.turn("S41A", i32::MIN).unwrap();
        assert_eq!(sim.rotary("S41A").unwrap(), 4);
    }

    #[test]
    fn rotaries_answer_in_their_own_packet_and_offset() {
        let mut sim = Trc1000Sim::new();
        sim.turn("S41A", 1).unwrap();
        sim.turn("S44A", 7).unwrap();
        sim.turn("S44B", 8).unwrap();
        sim.turn("S40", 14).unwrap();
        assert_eq!(
            ask(&mut sim, Command::RequestRotary0),
            Some([0xC2, 1, 0, 0, 0, 0, 0, 7])
        );
        assert_eq!(
            ask(&mut sim, Command::RequestRotary1),
            Some([0xC3, 8, 0, 0, 0, 0, 0, 14])
        );
    }

    #[test]
    fn select_relay_changes_the_relay_and_gets_no_answer() {
        let mut sim = Trc1000Sim::new();
        assert_eq!(sim.relay().number(), 0);
        assert_eq!(sim.relay_commands(), 0);
        assert_eq!(sim.receive(&[0x05, 0x14, 0, 0, 0, 0, 0, 0]), None);
        assert_eq!(sim.relay().number(), 5);
        // Don't-care bits do not change the selection.
        assert_eq!(sim.receive(&[0x05, 0xEF, 0, 0, 0, 0, 0, 0]), None);
        assert_eq!(sim.relay().number(), 3);
        assert_eq!(sim.relay_commands(), 2);
    }

    #[test]
    fn unknown_commands_get_no_answer_and_change_nothing() {
        let mut sim = Trc1000Sim::new();
        sim.press("S1").unwrap();
        let before = (sim.relay(), sim.switches(), sim.rotaries());
        for first in [0x00u8, 0x04, 0x06, 0x40, 0x44, 0xC1, 0xFF] {
            assert_eq!(sim.receive(&[first, 0x14, 1, 1, 1, 1, 1, 1]), None);
        }
        assert_eq!(before, (sim.relay(), sim.switches(), sim.rotaries()));
    }
}
