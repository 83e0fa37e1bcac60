//! `script_may_change` (a TRP-C29U's table in rig.toml): which of the fail-safe settings that
//! rig.toml gives the module its script may change. A setting rig.toml does not give is the
//! script's to set; one it gives (safe value, power-on value, watchdog) may only be made
//! stronger (a watchdog on or shorter) unless it is listed here.

use super::error::ProblemKind;
use super::reader::{bad, type_name, TableRef};
use toml::de::DeValue;

/// The key, as written in rig.toml.
pub const KEY: &str = "script_may_change";

/// The settings `script_may_change` can list.
pub const SETTINGS: &[&str] = &["safe_value", "power_on_value", "watchdog"];

/// Which fail-safe settings of a module its script may change from what rig.toml says.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ScriptMayChange {
    /// The safe value (also the runner's own safe state for the module).
    pub safe_value: bool,
    /// The power-on value.
    pub power_on_value: bool,
    /// The host watchdog: turn it off or lengthen it (turning it on or shortening it is
    /// always allowed).
    pub watchdog: bool,
}

impl ScriptMayChange {
    /// Everything: rig.toml sets none of them.
    pub const ALL: Self = Self {
        safe_value: true,
        power_on_value: true,
        watchdog: true,
    };

    /// What a module's `table` allows: each setting the table does not give, and each listed
    /// in `listed` (the value of `script_may_change`, already read).
    pub(super) fn of(table: &TableRef<'_, '_>, listed: &[String]) -> Self {
        let may = |key: &str| table.get(key).is_none() || listed.iter().any(|l| l == key);
        Self {
            safe_value: may("safe_value"),
            power_on_value: may("power_on_value"),
            watchdog: may("watchdog"),
        }
    }
}

/// Reads the list: each entry one of `SETTINGS`.
pub(super) fn read(v: &DeValue<'_>) -> Result<Vec<String>, ProblemKind> {
    let DeValue::Array(items) = v else {
        return Err(ProblemKind::WrongType {
            expected: r#"a list of settings (["safe_value", "watchdog"])"#,
            found: type_name(v),
        });
    };
    items
        .iter()
        .map(|item| match item.get_ref() {
            DeValue::String(s) if SETTINGS.contains(&s.as_ref()) => Ok(s.to_string()),
            other => Err(bad(
                other,
                r#"is not a setting a script may be allowed to change; use "safe_value", "power_on_value" or "watchdog""#,
            )),
        })
        .collect()
}
