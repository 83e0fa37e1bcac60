//! The names rig.toml gives a device's points (`[devices.io.names]`: `DI0 = "guard door"`):
//! read and checked here, shown beside the point wherever a person reads it, and taken by
//! scripts where they take a channel or a switch.

use super::error::ProblemKind;
use super::reader::{Reader, TableRef};
use crate::suggest::closest;
use std::collections::BTreeMap;
use toml::de::DeValue;

/// The key of the names table under a device.
pub(super) const KEY: &str = "names";

/// The longest name, in characters: it sits beside the point on a line of the log.
pub const MAX_NAME: usize = 40;

/// The names of one device's points, by point (`DI0`, `DO3`, `S12`, `S41A`, `relay2`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct PointNames {
    by_point: BTreeMap<String, String>,
}

/// Which points a kind of device has, for its names table.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Points {
    /// A TRP-C29U: DI0-DI7 and DO0-DO7.
    C29u,
    /// A TRC1000: switches S1-S45, rotaries S37-S40 and S41A-S45B, relay positions
    /// relay0-relay7.
    Trc1000,
}

impl Points {
    /// Every point of the kind, in the order people count them.
    pub fn all(self) -> Vec<String> {
        match self {
            Points::C29u => (0..8)
                .map(|n| format!("DI{n}"))
                .chain((0..8).map(|n| format!("DO{n}")))
                .collect(),
            Points::Trc1000 => (1..=45)
                .map(|n| format!("S{n}"))
                .chain((41..=45).flat_map(|n| [format!("S{n}A"), format!("S{n}B")]))
                .chain((0..8).map(|n| format!("relay{n}")))
                .collect(),
        }
    }

    /// Whether `key` is a point of the kind, written as the board is marked.
    pub fn has(self, key: &str) -> bool {
        self.all().iter().any(|p| p == key)
    }

    /// The points, as people are told them.
    fn told(self) -> &'static str {
        match self {
            Points::C29u => "DI0-DI7 and DO0-DO7",
            Points::Trc1000 => "S1-S45, S41A-S45B and relay0-relay7",
        }
    }

    fn device(self) -> &'static str {
        match self {
            Points::C29u => "a TRP-C29U",
            Points::Trc1000 => "a TRC1000",
        }
    }
}

impl PointNames {
    /// Names as given, unchecked (for a rig put together in code; rig.toml's are read with
    /// `read`).
    pub fn from_pairs<'a>(pairs: impl IntoIterator<Item = (&'a str, &'a str)>) -> Self {
        Self {
            by_point: pairs
                .into_iter()
                .map(|(p, n)| (p.to_string(), n.to_string()))
                .collect(),
        }
    }

    /// Whether no point is named.
    pub fn is_empty(&self) -> bool {
        self.by_point.is_empty()
    }

    /// The name of `point` (`DI0`), if it has one.
    pub fn name_of(&self, point: &str) -> Option<&str> {
        self.by_point.get(point).map(String::as_str)
    }

    /// The point called `name`, if one is.
    pub fn point_named(&self, name: &str) -> Option<&str> {
        self.by_point
            .iter()
            .find(|(_, n)| n.as_str() == name)
            .map(|(p, _)| p.as_str())
    }

    /// `point` as a person reads it: `DI0 "guard door"`, or `DI0` when it has no name.
    pub fn shown(&self, point: &str) -> String {
        match self.name_of(point) {
            Some(name) => format!("{point} \"{name}\""),
            None => point.to_string(),
        }
    }

    /// Every (point, name), by point.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &str)> {
        self.by_point.iter().map(|(p, n)| (p.as_str(), n.as_str()))
    }

    /// The names by point, as the snapshot shows them.
    pub fn to_map(&self) -> BTreeMap<String, String> {
        self.by_point.clone()
    }

    /// The name nearest to `name` among those given (a slip of the keyboard), for
    /// did-you-mean.
    pub fn nearest(&self, name: &str) -> Option<&str> {
        closest(name, self.by_point.values().map(String::as_str))
    }
}

/// Reads the `names` table of device table `t`, whose points are `points`: each key a point
/// of the device, each value a name no other of its points has.
pub(super) fn read(r: &mut Reader<'_>, t: &TableRef<'_, '_>, points: Points) -> PointNames {
    let Some(value) = t.get(KEY) else {
        return PointNames::default();
    };
    let DeValue::Table(table) = value.get_ref() else {
        r.report(
            &value.span(),
            t.key_path(KEY),
            ProblemKind::WrongType {
                expected: "a table of names ([devices.NAME.names], DI0 = \"guard door\")",
                found: super::reader::type_name(value.get_ref()),
            },
        );
        return PointNames::default();
    };
    let table = TableRef {
        path: t.key_path(KEY),
        span: value.span(),
        table,
    };
    let all = points.all();
    let mut names = PointNames::default();
    for (key, value) in table.table.iter() {
        let point: &str = key.get_ref();
        if !all.iter().any(|p| p == point) {
            let near = all
                .iter()
                .find(|p| p.eq_ignore_ascii_case(point))
                .map(String::as_str)
                .or_else(|| closest(point, all.iter().map(String::as_str)))
                .map(str::to_string);
            r.report(
                &key.span(),
                table.key_path(point),
                ProblemKind::UnknownPoint {
                    device: points.device(),
                    points: points.told(),
                    near,
                },
            );
            continue;
        }
        let Some(name) = r.read(&table, point, |v| name(v, point, &all)) else {
            continue;
        };
        if let Some(other) = names.point_named(&name) {
            let other = other.to_string();
            r.report(
                &value.span(),
                table.key_path(point),
                ProblemKind::BadValue {
                    value: format!("{name:?}"),
                    reason: format!(
                        "is already the name of {other}; give each point a name of its own \
                         (a script finds the point by it)"
                    ),
                },
            );
            continue;
        }
        names.by_point.insert(point.to_string(), name);
    }
    names
}

/// A name: printable, 1-`MAX_NAME` characters, no `"`, no spaces at either end, and not
/// itself a point of the device (a script could not tell which is meant).
fn name(v: &DeValue<'_>, point: &str, points: &[String]) -> Result<String, ProblemKind> {
    let name = super::reader::string(v)?;
    let bad = |reason: String| ProblemKind::BadValue {
        value: format!("{name:?}"),
        reason,
    };
    let fits = !name.is_empty()
        && name.chars().count() <= MAX_NAME
        && name.trim() == name
        && !name.chars().any(|c| c.is_control() || c == '"');
    if !fits {
        return Err(bad(format!(
            "is not a name for {point}; use 1-{MAX_NAME} characters, no quotes or control \
             characters, no spaces at either end"
        )));
    }
    if points.iter().any(|p| p.eq_ignore_ascii_case(&name)) {
        return Err(bad(format!(
            "is a point of the device itself; name {point} in words (\"guard door\")"
        )));
    }
    Ok(name)
}

#[cfg(test)]
mod tests {
    use super::super::{DeviceConfig, RigConfig};
    use super::*;

    fn names_of(device: &str, table: &str) -> Result<PointNames, String> {
        let head = if device == "io" {
            "[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\n"
        } else {
            "[devices.panel]\nkind = \"trc1000\"\n"
        };
        let text = format!("{head}[devices.{device}.names]\n{table}\n");
        let c = RigConfig::parse(&text, "rig.toml").map_err(|e| e.to_string())?;
        Ok(match c.devices.get(device) {
            Some(DeviceConfig::C29u(io)) => io.names.clone(),
            Some(DeviceConfig::Trc1000(p)) => p.names.clone(),
            None => panic!("no {device}"),
        })
    }

    #[test]
    fn a_module_s_channels_and_a_panel_s_switches_rotaries_and_relay_are_named_alike() {
        let io = names_of("io", "DI0 = \"guard door\"\nDO0 = \"motor\"").unwrap();
        assert_eq!(io.name_of("DI0"), Some("guard door"));
        assert_eq!(io.point_named("motor"), Some("DO0"));
        assert_eq!(io.shown("DI0"), "DI0 \"guard door\"");
        assert_eq!(io.shown("DI1"), "DI1");
        let panel = names_of(
            "panel",
            "S12 = \"cycle start\"\nS41A = \"die selector\"\nrelay3 = \"die B\"",
        )
        .unwrap();
        assert_eq!(panel.name_of("S12"), Some("cycle start"));
        assert_eq!(panel.point_named("die selector"), Some("S41A"));
        assert_eq!(panel.name_of("relay3"), Some("die B"));
    }

    #[test]
    fn an_unknown_point_is_refused_naming_its_key_with_the_nearest_point() {
        let e = names_of("io", "DI9 = \"x\"\ndo1 = \"y\"\nS12 = \"z\"").unwrap_err();
        let lines: Vec<&str> = e.lines().collect();
        assert_eq!(lines.len(), 3, "{e}");
        assert!(
            lines[0].starts_with("rig.toml:5: devices.io.names.DI9: not a point of a TRP-C29U"),
            "{e}"
        );
        assert!(lines[0].contains("DI0-DI7 and DO0-DO7"), "{e}");
        assert!(lines[1].contains("devices.io.names.do1"), "{e}");
        assert!(lines[1].contains("did you mean `DO1`?"), "{e}");
        assert!(lines[2].contains("devices.io.names.S12"), "{e}");
        let e = names_of("panel", "S46 = \"x\"").unwrap_err();
        assert!(
            e.contains("devices.panel.names.S46: not a point of a TRC1000"),
            "{e}"
        );
    }

    #[test]
    fn names_are_words_of_their_own() {
        for (table, why) in [
            ("DI0 = \"\"", "not a name for DI0"),
            ("DI0 = \" door\"", "not a name for DI0"),
            ("DI0 = \"a\\u0007\"", "not a name for DI0"),
            ("DI0 = \"DO3\"", "is a point of the device itself"),
            (
                "DI0 = \"door\"\nDI1 = \"door\"",
                "is already the name of DI0",
            ),
            ("DI0 = 3", "expected a string"),
        ] {
            let e = names_of("io", table).unwrap_err();
            assert!(e.contains(why), "{table}: {e}");
        }
        let long = "x".repeat(MAX_NAME + 1);
        assert!(names_of("io", &format!("DI0 = \"{long}\"")).is_err());
    }
}
