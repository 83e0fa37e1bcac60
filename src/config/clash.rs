//! Devices that would answer to one address: two TRP-C29U entries at the same port and ID
//! (both drive one module, each with its own safe value), modules on one line at different
//! speeds, two TRC1000 entries for the same board. Each clash is a problem at the later
//! entry that names the earlier one and its line.

use super::device::{DeviceConfig, Port, Trc1000Address};
use super::error::ProblemKind;
use super::reader::{Reader, TableRef};
use std::collections::BTreeMap;

/// Where an entry is, for messages: its key path and its line.
struct Entry<'c> {
    name: &'c str,
    line: usize,
    offset: usize,
    config: &'c DeviceConfig,
}

/// Reports every pair of `devices` that would reach the same device or share a line at two
/// speeds; `table` is the `[devices]` table they were read from (for their lines).
pub(super) fn check(
    r: &mut Reader<'_>,
    table: &TableRef<'_, '_>,
    devices: &BTreeMap<String, DeviceConfig>,
) {
    let mut entries: Vec<Entry<'_>> = devices
        .iter()
        .filter_map(|(name, config)| {
            let value = table.get(name)?;
            let offset = value.span().start;
            Some(Entry {
                name,
                line: r.line_of(offset),
                offset,
                config,
            })
        })
        .collect();
    // In the order of the file, so the message sits at the later entry.
    entries.sort_by_key(|e| e.offset);
    for (i, later) in entries.iter().enumerate() {
        let found = entries
            .get(..i)
            .unwrap_or_default()
            .iter()
            .find_map(|e| clash(e.config, later.config).map(|c| (e, c)));
        let Some((earlier, (relation, detail))) = found else {
            continue;
        };
        r.report(
            &(later.offset..later.offset),
            table.key_path(later.name),
            ProblemKind::Clash {
                relation,
                other: table.key_path(earlier.name),
                other_line: earlier.line,
                detail,
            },
        );
    }
}

/// How `b` clashes with `a` ("is the same module as"), and what they share in words ending
/// with what to do; `None` if they may stand together.
fn clash(a: &DeviceConfig, b: &DeviceConfig) -> Option<(&'static str, String)> {
    match (a, b) {
        (DeviceConfig::C29u(a), DeviceConfig::C29u(b)) if a.port == b.port => {
            if a.port == Port::Simulated {
                return None;
            }
            if a.id == b.id {
                Some((
                    "is the same module as",
                    format!(
                        "TRP-C29U ID {} on {}; two entries would drive one module with two \
                         safe values. Give each module its own ID (`rigscript scan` lists the \
                         modules on a line) or remove one entry",
                        a.id, a.port
                    ),
                ))
            } else if a.baud != b.baud {
                Some((
                    "is on the same line as",
                    format!(
                        "{} at {} baud, and {} baud there; modules on one line must use one \
                         baud rate",
                        a.port, b.baud, a.baud
                    ),
                ))
            } else {
                None
            }
        }
        (DeviceConfig::Trc1000(a), DeviceConfig::Trc1000(b)) if a.address == b.address => {
            let board = match a.address {
                Trc1000Address::Unit(u) => format!("unit {u}"),
                Trc1000Address::BusAddress { bus, address } => {
                    format!("USB device {bus}:{address}")
                }
            };
            Some((
                "is the same board as",
                format!(
                    "TRC1000 {board}; set each board's DIP switch to its own unit, or name \
                     it by `device = \"BUS:ADDRESS\"`, or remove one entry"
                ),
            ))
        }
        _ => None,
    }
}
