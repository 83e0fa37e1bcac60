//! The rig's devices as the runtime holds them: the real drivers (`device::c29u::C29u`,
//! `device::trc1000::Trc1000`) over real links or in-memory links to simulators, with the
//! per-tick input snapshots, the outputs the script wants, and the link's health.

mod c29u;
mod identity;
mod open;
mod settings;
mod sim;
mod takeover;
mod trc;

pub mod links;

/// Where callers not yet composing their own run find the opener of a (partly) simulated rig.
pub use c29u::C29uDevice;
pub use identity::{CheckFinding, Found, ModuleCheck};
/// The driver options a rig.toml module gets, for the fault search's harness (tests/).
#[cfg(feature = "internals")]
pub use open::c29u_options;
pub use open::{open_devices_with, OpenError, Opened, SimLinks};
pub use settings::SettingRefused;
pub use sim::{FieldError, SimDevice, SimRig, SwappedModule};
pub use takeover::{ControlNotes, Takeover};
pub use trc::TrcDevice;

use crate::device::c29u::C29uError;
use crate::device::cancel::Cancel;
use crate::device::trc1000::Trc1000Error;
use std::time::Duration;

/// Why a device operation failed.
#[derive(Debug, thiserror::Error)]
pub enum DeviceError {
    /// From the TRC1000 driver.
    #[error(transparent)]
    Trc(#[from] Trc1000Error),
    /// From the TRP-C29U driver.
    #[error(transparent)]
    C29u(#[from] C29uError),
    /// A script may not change that setting (or not so).
    #[error(transparent)]
    Refused(Box<SettingRefused>),
    /// The device is lost; the operation was not tried.
    #[error("{device} is offline (lost {ago:.1?} ago: {cause}); the operation was not done")]
    Offline {
        /// The device's name.
        device: String,
        /// How long ago it was lost.
        ago: Duration,
        /// Why it was lost.
        cause: String,
    },
}

impl DeviceError {
    /// Whether the device could not be reached (no answer, a garbled one, a link failure), as
    /// opposed to a device that answered "no".
    pub fn is_comm_failure(&self) -> bool {
        match self {
            DeviceError::Trc(e) => {
                matches!(e, Trc1000Error::Link(_) | Trc1000Error::Timeout { .. })
            }
            DeviceError::C29u(e) => matches!(
                e,
                C29uError::Link(_) | C29uError::Timeout { .. } | C29uError::Garbled { .. }
            ),
            DeviceError::Offline { .. } | DeviceError::Refused(_) => false,
        }
    }

    /// Whether the link itself failed (worth reopening), not just the device's answer.
    pub fn is_link_failure(&self) -> bool {
        matches!(
            self,
            DeviceError::Trc(Trc1000Error::Link(_)) | DeviceError::C29u(C29uError::Link(_))
        )
    }

    /// Whether a stop cut the operation short: nothing is known of the device, which is not
    /// lost for it.
    pub fn is_cancelled(&self) -> bool {
        matches!(
            self,
            DeviceError::C29u(C29uError::Cancelled { .. })
                | DeviceError::Trc(Trc1000Error::Cancelled { .. })
        )
    }

    /// Whether a TRP-C29U refused because its host watchdog has fired.
    pub fn is_safe_mode(&self) -> bool {
        matches!(self, DeviceError::C29u(C29uError::SafeMode { .. }))
    }
}

/// Whether a device answers, and since when it does not.
#[derive(Debug, Clone, Default)]
pub struct Health {
    /// When it stopped answering (`None` while it answers).
    pub(super) lost_at: Option<Duration>,
    /// When to try it again.
    pub(super) next_retry: Duration,
    /// Why it stopped answering.
    pub(super) cause: String,
    /// The link itself failed: reopen it before trying again.
    pub(super) link_failed: bool,
    /// When it last answered (as far as the runner noted: reads, commands, feeds, probes).
    pub(super) heard_at: Duration,
    /// The tick the script last read it in (0: none): a device read every tick is left to
    /// the next tick's read rather than asked between ticks.
    pub(super) read_tick: u64,
}

impl Health {
    /// Whether the device answers.
    pub fn online(&self) -> bool {
        self.lost_at.is_none()
    }

    /// When it stopped answering (`None` while it answers).
    pub fn lost_at(&self) -> Option<Duration> {
        self.lost_at
    }

    /// When to try it again (while lost).
    #[inline]
    pub fn next_retry(&self) -> Duration {
        self.next_retry
    }

    /// Why it stopped answering.
    pub fn cause(&self) -> &str {
        &self.cause
    }

    /// Whether the link itself failed: reopen it before trying again.
    pub fn link_failed(&self) -> bool {
        self.link_failed
    }

    /// When it last answered (as far as the runner noted).
    #[inline]
    pub fn heard_at(&self) -> Duration {
        self.heard_at
    }

    /// Whether the script read it in `tick` (0: none).
    #[inline]
    pub fn read_in(&self, tick: u64) -> bool {
        self.read_tick == tick && tick > 0
    }

    /// It answered at `at`.
    #[inline]
    pub fn heard(&mut self, at: Duration) {
        self.heard_at = self.heard_at.max(at);
    }

    /// The script read it in `tick`.
    #[inline]
    pub fn note_read(&mut self, tick: u64) {
        self.read_tick = tick;
    }

    /// A try of it while lost failed with `error`: tried again at `retry_at`.
    pub fn note_try_failed(&mut self, error: &DeviceError, retry_at: Duration) {
        self.next_retry = retry_at;
        self.link_failed = self.link_failed || error.is_link_failure();
    }

    /// Moves a retry time already past at `now` on by `interval` (while lost).
    pub fn put_off_retry(&mut self, now: Duration, interval: Duration) {
        if !self.online() && self.next_retry <= now {
            self.next_retry = now.saturating_add(interval);
        }
    }

    /// Marks the device lost at `now` (keeps the first time); true if it was online.
    pub fn lose(&mut self, now: Duration, error: &DeviceError, retry_in: Duration) -> bool {
        let was_online = self.lost_at.is_none();
        let cause = error.to_string();
        self.link_failed = self.link_failed || error.is_link_failure();
        if was_online {
            self.lost_at = Some(now);
        }
        self.cause = cause;
        self.next_retry = now.saturating_add(retry_in);
        was_online
    }

    /// Marks the device back.
    pub fn back(&mut self) {
        self.lost_at = None;
        self.cause.clear();
        self.link_failed = false;
    }

    /// How long it has been lost at `now` (zero while online).
    pub fn lost_for(&self, now: Duration) -> Duration {
        self.lost_at
            .map_or(Duration::ZERO, |at| now.saturating_sub(at))
    }

    /// The error to give an operation that was not tried because the device is lost.
    pub fn offline_error(&self, device: &str, now: Duration) -> DeviceError {
        DeviceError::Offline {
            device: device.to_string(),
            ago: self.lost_for(now),
            cause: self.cause.clone(),
        }
    }
}

/// An input value with the value read before it, and the tick it was read at (lazy reads:
/// the first access in a tick reads, later ones reuse it).
#[derive(Debug, Clone, Copy)]
pub struct Snapshot<T> {
    /// The latest value read.
    pub current: Option<T>,
    /// The value read before it.
    pub previous: Option<T>,
    /// The tick `current` was read at.
    pub tick: Option<u64>,
}

impl<T> Default for Snapshot<T> {
    fn default() -> Self {
        Self {
            current: None,
            previous: None,
            tick: None,
        }
    }
}

impl<T: Copy> Snapshot<T> {
    /// Whether `current` was read at `tick`.
    pub fn fresh(&self, tick: u64) -> bool {
        self.tick == Some(tick) && self.current.is_some()
    }

    /// Takes a new reading made at `tick`.
    pub fn update(&mut self, value: T, tick: u64) {
        self.previous = self.current;
        self.current = Some(value);
        self.tick = Some(tick);
    }

    /// `current`, or `other`'s if that was read at a later tick.
    pub fn or_later(&self, other: &Snapshot<T>) -> Option<T> {
        match (self.tick, other.tick) {
            (Some(mine), Some(theirs)) if theirs > mine => other.current.or(self.current),
            (None, Some(_)) => other.current,
            _ => self.current,
        }
    }

    /// (previous, current) if a reading was made at `tick` and there was one before it.
    pub fn change_at(&self, tick: u64) -> Option<(T, T)> {
        match (self.fresh(tick), self.previous, self.current) {
            (true, Some(p), Some(c)) => Some((p, c)),
            _ => None,
        }
    }
}

/// One device of the rig.
pub enum Device {
    /// A TRC1000 panel board.
    Trc(Box<TrcDevice>),
    /// A TRP-C29U I/O module.
    C29u(Box<C29uDevice>),
}

impl Device {
    /// The name scripts use.
    pub fn name(&self) -> &str {
        match self {
            Device::Trc(d) => &d.name,
            Device::C29u(d) => &d.name,
        }
    }

    /// What rig.toml calls the device's points (`[devices.NAME.names]`).
    pub fn names(&self) -> &crate::config::PointNames {
        match self {
            Device::Trc(d) => &d.config.names,
            Device::C29u(d) => &d.config.names,
        }
    }

    /// The TRC1000, if this is one.
    pub fn as_trc(&mut self) -> Option<&mut TrcDevice> {
        match self {
            Device::Trc(d) => Some(d),
            Device::C29u(_) => None,
        }
    }

    /// The TRP-C29U, if this is one.
    pub fn as_c29u(&mut self) -> Option<&mut C29uDevice> {
        match self {
            Device::C29u(d) => Some(d),
            Device::Trc(_) => None,
        }
    }

    /// The device's health.
    pub fn health(&self) -> &Health {
        match self {
            Device::Trc(d) => &d.health,
            Device::C29u(d) => &d.health,
        }
    }

    /// The device's health, to change.
    pub fn health_mut(&mut self) -> &mut Health {
        match self {
            Device::Trc(d) => &mut d.health,
            Device::C29u(d) => &mut d.health,
        }
    }

    /// The kind in words, for messages.
    pub fn kind_name(&self) -> &'static str {
        match self {
            Device::Trc(_) => "TRC1000",
            Device::C29u(_) => "TRP-C29U",
        }
    }

    /// Its link in words.
    pub fn describe(&self) -> String {
        match self {
            Device::Trc(d) => d.describe(),
            Device::C29u(d) => d.describe(),
        }
    }

    /// The script wants the safe values again (a restarted script starts from them); a
    /// TRC1000 without a safe relay keeps its relay.
    pub fn want_safe_state(&mut self) {
        match self {
            Device::Trc(d) => d.relay = d.config.safe_relay.unwrap_or(d.relay),
            Device::C29u(d) => d.outputs = d.config.safe_value,
        }
    }

    /// Cuts the device's exchanges short once `cancel` is set (see `device::cancel`).
    pub fn set_cancel(&mut self, cancel: &Cancel) {
        match self {
            Device::Trc(d) => d.driver.set_cancel(cancel.clone()),
            Device::C29u(d) => d.set_cancel(cancel),
        }
    }

    /// Reopens the link if it has one to reopen (real hardware), after a link failure.
    pub fn reopen(&mut self) -> Result<(), DeviceError> {
        match self {
            Device::Trc(d) => d.reopen(),
            Device::C29u(d) => d.reopen(),
        }
    }
}
