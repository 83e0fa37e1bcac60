//! Point names (rig.toml's `[devices.NAME.names]`) where a script takes a channel, a switch or
//! a rotary: `io.input("guard door")`, `panel.on_press("cycle start", ..)`. Resolved here for
//! a run and for `check`, so both say the same words.

use crate::config::PointNames;
use crate::protocol::trc1000::{Rotary, Switch};
use crate::suggest::closest;

/// Which of a module's channels a call takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Way {
    /// An input: DI0-DI7 (`input`, `counter`, `on_rise` ...).
    Input,
    /// An output: DO0-DO7 (`output`, `set_output`).
    Output,
}

impl Way {
    fn prefix(self) -> &'static str {
        match self {
            Way::Input => "DI",
            Way::Output => "DO",
        }
    }

    fn words(self) -> &'static str {
        match self {
            Way::Input => "an input",
            Way::Output => "an output",
        }
    }
}

/// The channel `text` means on the module `on` ("io (TRP-C29U)") whose points are called
/// `names`: the point as marked (`DI3`) or a name of one of its channels of `way`; else why
/// not.
pub fn channel_named(names: &PointNames, on: &str, text: &str, way: Way) -> Result<u8, String> {
    let prefix = way.prefix();
    let point = names.point_named(text).unwrap_or(text);
    if let Some(n) = point
        .strip_prefix(prefix)
        .and_then(|n| n.parse::<u8>().ok())
        .filter(|n| *n < 8)
    {
        return Ok(n);
    }
    if let Some(other) = names.point_named(text) {
        return Err(format!(
            "{text:?} names {other} of {on}, not {}: use {}",
            way.words(),
            told(names, prefix)
        ));
    }
    Err(format!(
        "no channel called {text:?} on {on}{}: use {}",
        did_you_mean(names, text, |p| p.starts_with(prefix)),
        told(names, prefix)
    ))
}

/// The switch `text` means on the panel `on` ("panel (TRC1000)"): `S12` (any case) or a name
/// of one.
pub fn switch_named(names: &PointNames, on: &str, text: &str) -> Result<Switch, String> {
    Switch::from_name(text)
        .or_else(|| names.point_named(text).and_then(Switch::from_name))
        .ok_or_else(|| {
            format!(
                "no switch called {text:?} on {on}{}: use S1-S45{}",
                did_you_mean(names, text, |p| Switch::from_name(p).is_some()),
                named(names, |p| Switch::from_name(p).is_some())
            )
        })
}

/// The rotary `text` means on the panel `on`: `S41A` or a name of one.
pub fn rotary_named(names: &PointNames, on: &str, text: &str) -> Result<Rotary, String> {
    Rotary::from_name(text)
        .or_else(|| names.point_named(text).and_then(Rotary::from_name))
        .ok_or_else(|| {
            format!(
                "no rotary called {text:?} on {on}{}: use S37-S40 or S41A/B-S45A/B{}",
                did_you_mean(names, text, |p| Rotary::from_name(p).is_some()),
                named(names, |p| Rotary::from_name(p).is_some())
            )
        })
}

/// ` (did you mean "guard door"?)` when a name of the points `fits` is a slip away.
fn did_you_mean(names: &PointNames, text: &str, fits: impl Fn(&str) -> bool) -> String {
    let near = closest(text, names.iter().filter(|(p, _)| fits(p)).map(|(_, n)| n));
    near.map_or(String::new(), |n| format!(" (did you mean {n:?}?)"))
}

/// `0-7 or its names DI0 "guard door", DI3 "parts"`.
fn told(names: &PointNames, prefix: &str) -> String {
    format!(
        "0-7{}",
        named(names, |p| p.starts_with(prefix) && p.len() == 3)
    )
}

/// ` or a name: S12 "cycle start", ...` for the named points that `fit`; nothing if none.
fn named(names: &PointNames, fits: impl Fn(&str) -> bool) -> String {
    let each: Vec<String> = names
        .iter()
        .filter(|(p, _)| fits(p))
        .map(|(p, _)| names.shown(p))
        .collect();
    if each.is_empty() {
        String::new()
    } else {
        format!(" or a name rig.toml gives: {}", each.join(", "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn io() -> PointNames {
        PointNames::from_pairs([("DI0", "guard door"), ("DI3", "parts"), ("DO0", "motor")])
    }

    #[test]
    fn a_channel_is_a_number_a_point_or_a_name_of_its_way() {
        let n = io();
        assert_eq!(
            channel_named(&n, "io (TRP-C29U)", "guard door", Way::Input),
            Ok(0)
        );
        assert_eq!(
            channel_named(&n, "io (TRP-C29U)", "parts", Way::Input),
            Ok(3)
        );
        assert_eq!(channel_named(&n, "io (TRP-C29U)", "DI5", Way::Input), Ok(5));
        assert_eq!(
            channel_named(&n, "io (TRP-C29U)", "motor", Way::Output),
            Ok(0)
        );
        let e = channel_named(&n, "io (TRP-C29U)", "motor", Way::Input).unwrap_err();
        assert!(
            e.contains("\"motor\" names DO0 of io (TRP-C29U), not an input"),
            "{e}"
        );
        let e = channel_named(&n, "io (TRP-C29U)", "gaurd door", Way::Input).unwrap_err();
        assert!(
            e.starts_with(
                "no channel called \"gaurd door\" on io (TRP-C29U) (did you mean \"guard door\"?)"
            ),
            "{e}"
        );
        assert!(e.ends_with("use 0-7 or a name rig.toml gives: DI0 \"guard door\", DI3 \"parts\""));
    }

    #[test]
    fn switches_and_rotaries_by_name() {
        let n = PointNames::from_pairs([("S12", "cycle start"), ("S41A", "die selector")]);
        assert_eq!(
            switch_named(&n, "panel (TRC1000)", "cycle start").map(Switch::name),
            Ok("S12")
        );
        assert_eq!(
            switch_named(&n, "panel (TRC1000)", "s12").map(Switch::name),
            Ok("S12")
        );
        assert_eq!(
            rotary_named(&n, "panel (TRC1000)", "die selector"),
            Ok(Rotary::S41A)
        );
        let e = switch_named(&n, "panel (TRC1000)", "cycle strat").unwrap_err();
        assert!(e.contains("(did you mean \"cycle start\"?)"), "{e}");
        assert!(switch_named(&n, "panel (TRC1000)", "die selector").is_err());
    }
}
