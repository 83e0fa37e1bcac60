//! The TRC1000 over real USB (libusb via rusb): find boards, claim interface 0, move 8-byte
//! interrupt packets with a timeout on every transfer.

use super::{LinkError, PacketLink};
use rusb::{Context, Device, DeviceHandle, UsbContext};
use std::fmt;
use std::path::Path;
use std::time::Duration;

/// USB vendor ID of every TRC board.
pub const VENDOR_ID: u16 = 0x0D59;
/// Product ID of unit 0; unit n (DIP switch, 0-3) is this + n.
pub const PRODUCT_ID_BASE: u16 = 0x02AC;
/// Highest unit number the DIP switch can set.
pub const MAX_UNIT: u8 = 3;
/// The interface that carries the interrupt endpoints.
pub const INTERFACE: u8 = 0;
/// Interrupt OUT endpoint (commands).
pub const ENDPOINT_OUT: u8 = 0x01;
/// Interrupt IN endpoint (responses).
pub const ENDPOINT_IN: u8 = 0x82;

/// Where the usbfs device nodes live on Linux; without it the machine has no USB to speak of.
const USBFS: &str = "/dev/bus/usb";
/// Hint for a board that cannot be found.
const HINT_NOT_FOUND: &str =
    "is it plugged in? `rigscript trc list` shows the boards this machine sees";
/// Hint for a board the operating system will not let us open.
const HINT_PERMISSION: &str =
    "install the udev rule (see README) or run as a user allowed to use the device";

/// The TRC1000 unit (0-3) a vendor/product pair belongs to, if it is a TRC1000 at all.
pub fn unit_of(vendor_id: u16, product_id: u16) -> Option<u8> {
    if vendor_id != VENDOR_ID {
        return None;
    }
    let unit = product_id.checked_sub(PRODUCT_ID_BASE)?;
    u8::try_from(unit).ok().filter(|u| *u <= MAX_UNIT)
}

/// Which board to open.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum UsbTarget {
    /// By DIP-switch unit 0-3 (product ID 0x02AC + unit).
    Unit(u8),
    /// By USB bus number and device address, for two boards that share a unit.
    BusAddress {
        /// The USB bus number (as `lsusb` shows it).
        bus: u8,
        /// The device's address on that bus.
        address: u8,
    },
}

impl fmt::Display for UsbTarget {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            UsbTarget::Unit(u) => write!(f, "TRC1000 unit {u}"),
            UsbTarget::BusAddress { bus, address } => {
                write!(f, "TRC1000 at USB {bus:03}:{address:03}")
            }
        }
    }
}

/// A TRC1000 seen on the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub struct BoardInfo {
    /// DIP-switch unit, 0-3.
    pub unit: u8,
    /// USB bus number.
    pub bus: u8,
    /// USB device address on that bus.
    pub address: u8,
    /// USB product ID (0x02AC + unit).
    pub product_id: u16,
}

impl BoardInfo {
    /// Its usbfs node, which libusb opens and a program using the board keeps open.
    pub fn node(&self) -> std::path::PathBuf {
        Path::new(USBFS).join(format!("{:03}/{:03}", self.bus, self.address))
    }
}

impl fmt::Display for BoardInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "TRC1000 unit {} (USB {:03}:{:03})",
            self.unit, self.bus, self.address
        )
    }
}

/// A libusb context, or `None` when this machine has no USB at all (no usbfs), which is not an
/// error for listing: there are simply no boards.
fn context() -> Result<Option<Context>, LinkError> {
    match Context::new() {
        Ok(ctx) => Ok(Some(ctx)),
        Err(_) if !Path::new(USBFS).exists() => Ok(None),
        Err(e) => Err(LinkError::Usb {
            what: "USB".into(),
            detail: format!("cannot start libusb: {e}"),
        }),
    }
}

/// Every TRC1000 on this machine with its device handle, in bus/address order.
fn boards(ctx: &Context) -> Result<Vec<(BoardInfo, Device<Context>)>, LinkError> {
    let devices = match ctx.devices() {
        Ok(d) => d,
        Err(_) if !Path::new(USBFS).exists() => return Ok(Vec::new()),
        Err(e) => return Err(map_err(e, "USB device list", false)),
    };
    let mut found = Vec::new();
    for device in devices.iter() {
        // A device whose descriptor cannot be read is not one we can use; skip it.
        let Ok(desc) = device.device_descriptor() else {
            continue;
        };
        if let Some(unit) = unit_of(desc.vendor_id(), desc.product_id()) {
            let info = BoardInfo {
                unit,
                bus: device.bus_number(),
                address: device.address(),
                product_id: desc.product_id(),
            };
            found.push((info, device));
        }
    }
    found.sort_by_key(|(i, _)| (i.bus, i.address));
    Ok(found)
}

/// The TRC1000 boards on this machine; an empty list (not an error) on a machine without USB.
pub fn list_boards() -> Result<Vec<BoardInfo>, LinkError> {
    match context()? {
        Some(ctx) => Ok(boards(&ctx)?.into_iter().map(|(i, _)| i).collect()),
        None => Ok(Vec::new()),
    }
}

/// As `map_err` for the board `info`: a busy interface names the processes that have the
/// board's node open (`link::holders`), so a running rig can be named.
fn map_err_at(e: rusb::Error, info: &BoardInfo, in_use: bool) -> LinkError {
    match e {
        rusb::Error::Busy => LinkError::Busy {
            what: info.to_string(),
            holders: Box::new(super::holders::holders_of(&info.node())),
        },
        other => map_err(other, &info.to_string(), in_use),
    }
}

/// Maps a libusb error to a `LinkError` that says what to try. `in_use` = the device was open
/// and working, so "no device" means it went away.
fn map_err(e: rusb::Error, what: &str, in_use: bool) -> LinkError {
    let what = what.to_string();
    match e {
        rusb::Error::Access => LinkError::PermissionDenied {
            what,
            hint: HINT_PERMISSION.into(),
        },
        rusb::Error::NoDevice if in_use => LinkError::Disconnected {
            what,
            detail:
                "the board went away (cable unplugged or board reset); reconnect it and try again"
                    .into(),
        },
        rusb::Error::NoDevice | rusb::Error::NotFound => LinkError::NotFound {
            what,
            hint: HINT_NOT_FOUND.into(),
        },
        rusb::Error::Busy => LinkError::Usb {
            what,
            detail: "interface 0 is busy: another program or driver holds the board; close it \
                     and try again"
                .into(),
        },
        rusb::Error::Pipe => LinkError::Usb {
            what,
            detail: "endpoint stalled; unplug and reconnect the board".into(),
        },
        other => LinkError::Usb {
            what,
            detail: other.to_string(),
        },
    }
}

/// libusb treats a zero timeout as "wait forever"; every transfer here must end.
fn transfer_timeout(timeout: Duration) -> Duration {
    timeout.clamp(Duration::from_millis(1), Duration::from_secs(3600))
}

/// An open, claimed TRC1000: 8-byte packets OUT on 0x01 and IN on 0x82.
pub struct UsbPacketLink {
    handle: DeviceHandle<Context>,
    info: BoardInfo,
    /// We detached the kernel's driver and owe it the interface back.
    reattach: bool,
}

impl UsbPacketLink {
    /// Opens and claims the board named by `target`, detaching the kernel's HID driver from
    /// interface 0 if it holds it (re-attached when the link is dropped).
    pub fn open(target: UsbTarget) -> Result<Self, LinkError> {
        let name = target.to_string();
        let Some(ctx) = context()? else {
            return Err(LinkError::NotFound {
                what: name,
                hint: format!(
                    "this machine has no USB devices ({USBFS} is missing); {HINT_NOT_FOUND}"
                ),
            });
        };
        let all = boards(&ctx)?;
        let (info, device) = pick(target, all, &ctx)?;
        let what = info.to_string();
        let handle = device.open().map_err(|e| map_err_at(e, &info, false))?;

        let reattach = match handle.kernel_driver_active(INTERFACE) {
            // Only ever take the interface from the kernel for our own board.
            Ok(true) if unit_of(VENDOR_ID, info.product_id).is_some() => {
                handle
                    .detach_kernel_driver(INTERFACE)
                    .map_err(|e| map_err_at(e, &info, false))?;
                true
            }
            Ok(_) => false,
            Err(rusb::Error::NoDevice) => {
                return Err(map_err(rusb::Error::NoDevice, &what, true));
            }
            // NotSupported (other platforms, emulated devices) and anything else: we cannot
            // tell, so assume no driver holds it; claiming will report a busy interface.
            Err(_) => false,
        };
        if let Err(e) = handle.claim_interface(INTERFACE) {
            if reattach {
                let _ = handle.attach_kernel_driver(INTERFACE);
            }
            return Err(map_err_at(e, &info, false));
        }
        Ok(Self {
            handle,
            info,
            reattach,
        })
    }

    /// The board this link talks to.
    pub fn info(&self) -> BoardInfo {
        self.info
    }
}

/// Chooses the one board `target` names among `all`.
fn pick(
    target: UsbTarget,
    all: Vec<(BoardInfo, Device<Context>)>,
    ctx: &Context,
) -> Result<(BoardInfo, Device<Context>), LinkError> {
    let name = target.to_string();
    match target {
        UsbTarget::Unit(unit) => {
            let mut matching: Vec<_> = all.into_iter().filter(|(i, _)| i.unit == unit).collect();
            if matching.len() > 1 {
                let places: Vec<String> = matching
                    .iter()
                    .map(|(i, _)| format!("{:03}:{:03}", i.bus, i.address))
                    .collect();
                return Err(LinkError::Usb {
                    what: name,
                    detail: format!(
                        "{} boards are set to unit {unit} (at {}); choose one with --device BUS:ADDR \
                         or give them different DIP switch settings",
                        matching.len(),
                        places.join(", ")
                    ),
                });
            }
            matching.pop().ok_or_else(|| LinkError::NotFound {
                what: format!(
                    "{name} (USB {VENDOR_ID:04x}:{:04x})",
                    PRODUCT_ID_BASE.saturating_add(u16::from(unit))
                ),
                hint: HINT_NOT_FOUND.into(),
            })
        }
        UsbTarget::BusAddress { bus, address } => {
            if let Some(found) = all
                .into_iter()
                .find(|(i, _)| i.bus == bus && i.address == address)
            {
                return Ok(found);
            }
            // Say whether something else sits there, so a typo in BUS:ADDR is obvious.
            let other = ctx.devices().ok().and_then(|list| {
                list.iter()
                    .find(|d| d.bus_number() == bus && d.address() == address)
                    .and_then(|d| d.device_descriptor().ok())
                    .map(|d| format!("{:04x}:{:04x}", d.vendor_id(), d.product_id()))
            });
            Err(LinkError::NotFound {
                what: name,
                hint: match other {
                    Some(id) => format!(
                        "the device there is {id}, not a TRC1000 ({VENDOR_ID:04x}:02ac-02af); \
                         `rigscript trc list` shows the boards"
                    ),
                    None => HINT_NOT_FOUND.into(),
                },
            })
        }
    }
}

impl PacketLink for UsbPacketLink {
    fn send(&mut self, packet: &[u8; 8], timeout: Duration) -> Result<(), LinkError> {
        let what = self.info.to_string();
        match self
            .handle
            .write_interrupt(ENDPOINT_OUT, packet, transfer_timeout(timeout))
        {
            Ok(8) => Ok(()),
            Ok(n) => Err(LinkError::Usb {
                what,
                detail: format!("sent only {n} of 8 bytes"),
            }),
            Err(rusb::Error::Timeout) => Err(LinkError::Io {
                what,
                source: std::io::Error::new(
                    std::io::ErrorKind::TimedOut,
                    format!(
                        "the board did not take a packet within {} ms; check it is powered",
                        timeout.as_millis()
                    ),
                ),
            }),
            Err(e) => Err(map_err(e, &what, true)),
        }
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<[u8; 8]>, LinkError> {
        let mut buf = [0u8; 8];
        match self
            .handle
            .read_interrupt(ENDPOINT_IN, &mut buf, transfer_timeout(timeout))
        {
            // Bytes the board did not send stay zero: unused bytes are ignored anyway.
            Ok(0) => Ok(None),
            Ok(_) => Ok(Some(buf)),
            Err(rusb::Error::Timeout) => Ok(None),
            Err(e) => Err(map_err(e, &self.info.to_string(), true)),
        }
    }

    fn describe(&self) -> String {
        self.info.to_string()
    }
}

impl Drop for UsbPacketLink {
    fn drop(&mut self) {
        // Best effort: the board may already be gone, and there is no one to tell.
        let _ = self.handle.release_interface(INTERFACE);
        if self.reattach {
            let _ = self.handle.attach_kernel_driver(INTERFACE);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_are_product_ids_02ac_to_02af_of_vendor_0d59() {
        assert_eq!(unit_of(0x0D59, 0x02AC), Some(0));
        assert_eq!(unit_of(0x0D59, 0x02AF), Some(3));
        assert_eq!(unit_of(0x0D59, 0x02B0), None);
        assert_eq!(unit_of(0x0D59, 0x02AB), None);
        assert_eq!(unit_of(0x0D59, 0x0000), None);
        assert_eq!(unit_of(0x1209, 0x02AC), None);
    }

    #[test]
    fn errors_say_what_to_try() {
        let e = map_err(rusb::Error::NotFound, "TRC1000 unit 1", false);
        assert!(matches!(e, LinkError::NotFound { .. }));
        assert!(e.to_string().contains("rigscript trc list"), "{e}");
        let e = map_err(rusb::Error::Access, "TRC1000 unit 0", false);
        assert!(matches!(e, LinkError::PermissionDenied { .. }));
        assert!(e.to_string().contains("udev rule"), "{e}");
        let e = map_err(rusb::Error::NoDevice, "TRC1000 unit 0", true);
        assert!(matches!(e, LinkError::Disconnected { .. }), "{e}");
        let e = map_err(rusb::Error::NoDevice, "TRC1000 unit 0", false);
        assert!(matches!(e, LinkError::NotFound { .. }), "{e}");
    }

    #[test]
    fn a_claimed_board_is_busy_with_the_holders_of_its_usbfs_node() {
        let info = BoardInfo {
            unit: 0,
            bus: 1,
            address: 4,
            product_id: PRODUCT_ID_BASE,
        };
        assert_eq!(info.node(), Path::new("/dev/bus/usb/001/004"));
        let e = map_err_at(rusb::Error::Busy, &info, false);
        let LinkError::Busy { holders, .. } = &e else {
            panic!("not busy: {e}");
        };
        assert_eq!(holders.device, Path::new("/dev/bus/usb/001/004"));
        assert!(
            e.to_string()
                .starts_with("TRC1000 unit 0 (USB 001:004) is busy: another program holds it"),
            "{e}"
        );
        let e = map_err_at(rusb::Error::Access, &info, false);
        assert!(matches!(e, LinkError::PermissionDenied { .. }), "{e}");
    }

    #[test]
    fn transfers_never_get_an_infinite_timeout() {
        assert_eq!(transfer_timeout(Duration::ZERO), Duration::from_millis(1));
        assert_eq!(
            transfer_timeout(Duration::from_millis(250)),
            Duration::from_millis(250)
        );
        assert_eq!(transfer_timeout(Duration::MAX), Duration::from_secs(3600));
    }

    #[test]
    fn targets_name_the_board_in_messages() {
        assert_eq!(UsbTarget::Unit(2).to_string(), "TRC1000 unit 2");
        assert_eq!(
            UsbTarget::BusAddress { bus: 1, address: 2 }.to_string(),
            "TRC1000 at USB 001:002"
        );
    }

    /// This machine has no USB at all (no /dev/bus/usb): listing is not an error there.
    #[test]
    fn listing_on_a_machine_without_usb_is_an_empty_list() {
        if Path::new(USBFS).exists() {
            // A machine with USB: listing must still work; boards may or may not be present.
            assert!(list_boards().is_ok());
            return;
        }
        assert_eq!(list_boards().unwrap(), Vec::new());
        let e = UsbPacketLink::open(UsbTarget::Unit(0)).err().unwrap();
        assert!(matches!(e, LinkError::NotFound { .. }), "{e}");
    }
}
