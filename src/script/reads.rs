//! What a script reads from its devices, item by item (a switch, a rotary, an input channel, a
//! counter, `.online`, the outputs it set...), tracked only when asked: `verify` weights its
//! random field toward what the script reads and reports what never changed.

use crate::protocol::trc1000::{Rotary, Switch};
use std::cell::RefCell;
use std::fmt;
use std::rc::Rc;

/// One thing a script can read from a device.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Item {
    /// A TRC1000 switch.
    Switch(Switch),
    /// A TRC1000 rotary.
    Rotary(Rotary),
    /// A TRP-C29U input channel (0-7).
    Input(u8),
    /// A TRP-C29U counter (0-7).
    Counter(u8),
    /// The TRP-C29U latches.
    Latches,
    /// `.online`.
    Online,
    /// The TRP-C29U outputs the script set.
    Outputs,
    /// The TRC1000 relay the script set.
    Relay,
}

const SWITCHES: u32 = 0;
const ROTARIES: u32 = SWITCHES + Switch::COUNT as u32;
const INPUTS: u32 = ROTARIES + Rotary::COUNT as u32;
const COUNTERS: u32 = INPUTS + 8;
const LATCHES: u32 = COUNTERS + 8;
const ONLINE: u32 = LATCHES + 1;
const OUTPUTS: u32 = ONLINE + 1;
const RELAY: u32 = OUTPUTS + 1;

/// Every switch.
pub const ALL_SWITCHES: u128 = ((1u128 << Switch::COUNT) - 1) << SWITCHES;
/// Every rotary.
#[cfg(test)]
pub const ALL_ROTARIES: u128 = ((1u128 << Rotary::COUNT) - 1) << ROTARIES;
/// Every input channel.
pub const ALL_INPUTS: u128 = 0xFF << INPUTS;
/// Every counter.
pub const ALL_COUNTERS: u128 = 0xFF << COUNTERS;

impl Item {
    /// The item's bit in a device's mask.
    pub fn bit(self) -> u32 {
        match self {
            Item::Switch(s) => SWITCHES + u32::from(s.number()) - 1,
            Item::Rotary(r) => {
                ROTARIES + Rotary::ALL.iter().position(|x| *x == r).unwrap_or(0) as u32
            }
            Item::Input(ch) => INPUTS + u32::from(ch.min(7)),
            Item::Counter(ch) => COUNTERS + u32::from(ch.min(7)),
            Item::Latches => LATCHES,
            Item::Online => ONLINE,
            Item::Outputs => OUTPUTS,
            Item::Relay => RELAY,
        }
    }

    /// The item at `bit`, if any.
    pub fn from_bit(bit: u32) -> Option<Item> {
        let small = |b: u32| u8::try_from(b).ok();
        Some(match bit {
            b if b < ROTARIES => Item::Switch(Switch::new(small(b - SWITCHES + 1)?)?),
            b if b < INPUTS => Item::Rotary(*Rotary::ALL.get((b - ROTARIES) as usize)?),
            b if b < COUNTERS => Item::Input(small(b - INPUTS)?),
            b if b < LATCHES => Item::Counter(small(b - COUNTERS)?),
            LATCHES => Item::Latches,
            ONLINE => Item::Online,
            OUTPUTS => Item::Outputs,
            RELAY => Item::Relay,
            _ => return None,
        })
    }

    /// The item's mask.
    pub fn mask(self) -> u128 {
        1u128 << self.bit()
    }
}

impl fmt::Display for Item {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Item::Switch(s) => write!(f, "{s}"),
            Item::Rotary(r) => f.write_str(r.name()),
            Item::Input(ch) => write!(f, "DI{ch}"),
            Item::Counter(ch) => write!(f, "counter DI{ch}"),
            Item::Latches => f.write_str("latches"),
            Item::Online => f.write_str("online"),
            Item::Outputs => f.write_str("outputs"),
            Item::Relay => f.write_str("relay"),
        }
    }
}

/// A set of (device index, item), one bit mask per device.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ReadSet {
    masks: Vec<u128>,
}

impl ReadSet {
    /// Adds the items of `mask` on device `dev`.
    pub fn add_mask(&mut self, dev: usize, mask: u128) {
        if self.masks.len() <= dev {
            self.masks.resize(dev + 1, 0);
        }
        if let Some(m) = self.masks.get_mut(dev) {
            *m |= mask;
        }
    }

    /// Adds one item.
    pub fn add(&mut self, dev: usize, item: Item) {
        self.add_mask(dev, item.mask());
    }

    /// Adds everything in `other`.
    pub fn union(&mut self, other: &ReadSet) {
        for (dev, m) in other.masks.iter().enumerate() {
            self.add_mask(dev, *m);
        }
    }

    /// The mask of device `dev`.
    pub fn mask(&self, dev: usize) -> u128 {
        self.masks.get(dev).copied().unwrap_or(0)
    }

    /// Whether `item` of device `dev` is in the set.
    pub fn contains(&self, dev: usize, item: Item) -> bool {
        self.mask(dev) & item.mask() != 0
    }

    /// Whether the set is empty.
    pub fn is_empty(&self) -> bool {
        self.masks.iter().all(|m| *m == 0)
    }

    /// Every (device, item), by device then item.
    pub fn items(&self) -> Vec<(usize, Item)> {
        let mut out = Vec::new();
        for (dev, m) in self.masks.iter().enumerate() {
            let mut rest = *m;
            while rest != 0 {
                let bit = rest.trailing_zeros();
                rest &= rest - 1;
                if let Some(item) = Item::from_bit(bit) {
                    out.push((dev, item));
                }
            }
        }
        out
    }
}

/// Tracks what the script reads while it runs; does nothing until `enable`d.
#[derive(Clone, Default)]
pub struct ReadTracker(Rc<RefCell<Option<ReadSet>>>);

impl ReadTracker {
    /// Starts tracking.
    pub fn enable(&self) {
        let mut t = self.0.borrow_mut();
        if t.is_none() {
            *t = Some(ReadSet::default());
        }
    }

    /// Notes that the items of `mask` on device `dev` were read.
    pub fn note(&self, dev: usize, mask: u128) {
        if let Some(set) = self.0.borrow_mut().as_mut() {
            set.add_mask(dev, mask);
        }
    }

    /// What was read since the last `take`.
    pub fn take(&self) -> ReadSet {
        self.0
            .borrow_mut()
            .as_mut()
            .map(std::mem::take)
            .unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_item_has_its_own_bit_and_comes_back_from_it() {
        let mut all = Vec::new();
        all.extend(Switch::all().map(Item::Switch));
        all.extend(Rotary::ALL.iter().map(|r| Item::Rotary(*r)));
        all.extend((0..8).map(Item::Input));
        all.extend((0..8).map(Item::Counter));
        all.extend([Item::Latches, Item::Online, Item::Outputs, Item::Relay]);
        let mut seen = 0u128;
        for item in all {
            assert_eq!(seen & item.mask(), 0, "{item} shares a bit");
            seen |= item.mask();
            assert_eq!(Item::from_bit(item.bit()), Some(item));
        }
        assert_eq!(seen.count_ones(), 45 + 14 + 8 + 8 + 4);
        assert_eq!(
            ALL_SWITCHES | ALL_ROTARIES | ALL_INPUTS | ALL_COUNTERS,
            seen & !(0xF << LATCHES)
        );
    }

    #[test]
    fn a_tracker_notes_only_once_enabled() {
        let t = ReadTracker::default();
        t.note(0, Item::Online.mask());
        assert!(t.take().is_empty());
        t.enable();
        t.note(1, Item::Input(3).mask());
        t.note(0, ALL_INPUTS);
        let set = t.take();
        assert!(set.contains(1, Item::Input(3)));
        assert!(!set.contains(1, Item::Input(2)));
        assert_eq!(set.items().len(), 9);
        assert!(t.take().is_empty(), "take empties it");
    }
}
