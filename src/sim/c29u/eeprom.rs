//! What the TRP-C29U keeps across resets and power cycles, and its JSON state file.

use super::config::ModuleConfig;
use super::C29uModelError;
use crate::protocol::c29u_ascii::ModuleName;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// The factory name of the module (8-14).
pub const DEFAULT_NAME: &str = "TRPC29";

/// Everything that survives a reset or power cycle (serde Serialize/Deserialize, JSON file).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Eeprom {
    /// ID, baud code and data format.
    pub config: ModuleConfig,
    /// Module name, 1..=6 printable ASCII characters.
    pub name: String,
    /// Counter values loaded at power on and reset (saved by `#IDCS` / `0F 03`).
    pub saved_counters: [u16; 8],
    /// DO value driven when the host watchdog fires.
    pub safe_value: u8,
    /// DO value driven at power on and after a reset.
    pub power_on_value: u8,
    /// Host watchdog timeout in 0.1 s units; 0 = disabled.
    pub watchdog_tenths: u8,
    /// LED operating mode, 0 or 1 (8-18, 10-10).
    pub led_mode: u8,
    /// The host watchdog has fired and not been disabled since; kept here so that safe mode
    /// survives a reset or power cycle (section 5, fail-safe reading).
    #[serde(default)]
    pub safe_mode: bool,
}

impl Eeprom {
    /// A factory-fresh module: factory config, name "TRPC29", counters 0, DO values 0,
    /// watchdog off, LED mode 0.
    pub fn factory() -> Self {
        Self {
            config: ModuleConfig::factory(),
            name: DEFAULT_NAME.to_owned(),
            saved_counters: [0; 8],
            safe_value: 0,
            power_on_value: 0,
            watchdog_tenths: 0,
            led_mode: 0,
            safe_mode: false,
        }
    }

    /// Reads and validates an EEPROM image from a JSON file; any failure names the file.
    pub fn load(path: impl AsRef<Path>) -> Result<Self, C29uModelError> {
        let path = path.as_ref();
        let text = std::fs::read_to_string(path).map_err(|e| file_error(path, &e))?;
        Self::from_json(&text).map_err(|reason| file_error(path, &reason))
    }

    /// Writes the image to a JSON file atomically: a temporary file beside it, then a rename.
    pub fn save(&self, path: impl AsRef<Path>) -> Result<(), C29uModelError> {
        let path = path.as_ref();
        let json = serde_json::to_string_pretty(self).map_err(|e| file_error(path, &e))?;
        let tmp = temp_path(path).ok_or_else(|| file_error(path, &"not a file path"))?;
        if let Err(e) = std::fs::write(&tmp, json.as_bytes()) {
            let _ = std::fs::remove_file(&tmp);
            return Err(file_error(path, &e));
        }
        std::fs::rename(&tmp, path).map_err(|e| {
            let _ = std::fs::remove_file(&tmp);
            file_error(path, &e)
        })
    }

    /// Parses and validates an image from JSON text.
    pub fn from_json(text: &str) -> Result<Self, String> {
        let image: Self =
            serde_json::from_str(text).map_err(|e| format!("not a valid EEPROM image: {e}"))?;
        image.validate().map_err(|e| e.to_string())?;
        Ok(image)
    }

    /// Checks every field holds a value the module could have stored.
    pub fn validate(&self) -> Result<(), C29uModelError> {
        self.config.validate()?;
        validate_name(&self.name)?;
        validate_led_mode(self.led_mode)
    }
}

impl Default for Eeprom {
    fn default() -> Self {
        Self::factory()
    }
}

/// Checks a module name by the rule of 8-14/8-17 ([`ModuleName`]).
pub fn validate_name(name: &str) -> Result<(), C29uModelError> {
    ModuleName::new(name).map(|_| ()).ok_or_else(|| {
        C29uModelError::BadValue(format!(
            "name {name:?}: 1..=6 printable ASCII characters (8-17)"
        ))
    })
}

/// Checks an LED mode: 0 or 1 (8-18, 10-10).
pub fn validate_led_mode(mode: u8) -> Result<(), C29uModelError> {
    if mode > 1 {
        return Err(C29uModelError::BadValue(format!(
            "LED mode {mode}: 0 or 1 (8-18)"
        )));
    }
    Ok(())
}

fn file_error(path: &Path, reason: &dyn std::fmt::Display) -> C29uModelError {
    C29uModelError::Io(format!("EEPROM state file {}: {reason}", path.display()))
}

/// A temporary name in the same directory, so the rename stays on one file system.
fn temp_path(path: &Path) -> Option<PathBuf> {
    let name = path.file_name()?.to_string_lossy();
    let tmp = format!(".{name}.tmp-{}", std::process::id());
    Some(path.with_file_name(tmp))
}
