//! Links move bytes or packets with timeouts; they know nothing of the protocols.
//!
//! A `ByteLink` carries a byte stream (a serial port, a TCP socket to a serial device server, or
//! memory to a simulator); a `PacketLink` carries the TRC1000's fixed 8-byte interrupt packets.

use line::LineState;
use std::os::fd::RawFd;
use std::time::Duration;

/// A descriptor on which the OS tells that a link has ended (a hang-up, an error, the peer's
/// close), looked at between exchanges without reading anything (`fd::ended`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Watch {
    /// The link's descriptor.
    pub fd: RawFd,
    /// A socket (its end is the peer's close or reset), else a terminal (a hang-up).
    pub socket: bool,
}

/// Why a link failed, with what to try next in the message.
#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    /// The port, host or USB device does not exist.
    #[error("{what} not found: {hint}")]
    NotFound {
        /// What was being opened or used (a port, a host, a USB device).
        what: String,
        /// What to check or try next.
        hint: String,
    },
    /// The operating system refused access.
    #[error("permission denied opening {what}: {hint}")]
    PermissionDenied {
        /// What was being opened or used (a port, a host, a USB device).
        what: String,
        /// How to get access (group, udev rule).
        hint: String,
    },
    /// Another program holds the port exclusively.
    #[error(
        "{what} is busy: another program holds it exclusively ({holders}); end that program or \
         wait for it to finish, then try again"
    )]
    Busy {
        /// What was being opened or used (a port, a host, a USB device).
        what: String,
        /// The programs that hold it, where the system tells.
        holders: Box<holders::Holders>,
    },
    /// The path exists but is not a serial port (a file, a directory, a device that is not a
    /// terminal).
    #[error(
        "{path} is not a serial port ({detail}): give a serial device such as /dev/ttyUSB0 \
         (`rigscript scan` lists them)"
    )]
    NotSerial {
        /// The path given.
        path: String,
        /// What it is instead.
        detail: String,
    },
    /// The device went away while in use (cable unplugged, server closed the connection).
    #[error("{what} disconnected: {detail}")]
    Disconnected {
        /// What was being opened or used (a port, a host, a USB device).
        what: String,
        /// What the system said.
        detail: String,
    },
    /// Any other I/O failure on the link.
    #[error("{what}: {source}")]
    Io {
        /// What was being opened or used (a port, a host, a USB device).
        what: String,
        /// The system's error.
        #[source]
        source: std::io::Error,
    },
    /// A libusb failure other than the ones above.
    #[error("{what}: USB error: {detail}")]
    Usb {
        /// What was being opened or used (a port, a host, a USB device).
        what: String,
        /// libusb's error.
        detail: String,
    },
}

impl LinkError {
    /// The processes holding the device, when it is busy: those locking it, else those with
    /// it open (a USB board's node is not locked, only claimed).
    pub fn held_by(&self) -> Vec<u32> {
        match self {
            LinkError::Busy { holders, .. } => holders.pids(),
            _ => Vec::new(),
        }
    }
}

/// A byte stream to one device (or one bus of devices) with per-call timeouts.
pub trait ByteLink: Send {
    /// Writes all of `bytes`, handing them to the line without waiting for them to leave it
    /// (the exchange layer knows how long they take); gives up if the line takes no data.
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError>;
    /// Reads what is available into `buf`, waiting up to `timeout` for the first byte (a zero
    /// `timeout` only looks); returns 0 when nothing arrived in time.
    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError>;
    /// Changes the line speed (a no-op where the link has none, such as TCP or memory).
    fn set_baud(&mut self, baud: u32) -> Result<(), LinkError>;
    /// The link in words for messages, such as `serial /dev/ttyUSB0 at 9600 baud`.
    fn describe(&self) -> String;
    /// The line's timing, kept here for the exchange layer so that every module on this link
    /// shares it; `None` for a link without one (a closed link).
    fn line(&mut self) -> Option<&mut LineState> {
        None
    }
    /// The descriptor the OS reports the link's end on, if it has one (`None`: a link in
    /// memory, or one whose end only a failing exchange tells).
    fn watch(&self) -> Option<Watch> {
        None
    }
}

/// A link that carries fixed 8-byte packets (the TRC1000's interrupt endpoints).
pub trait PacketLink: Send {
    /// Sends one packet, failing if it cannot be sent within `timeout`.
    fn send(&mut self, packet: &[u8; 8], timeout: Duration) -> Result<(), LinkError>;
    /// Receives one packet; `Ok(None)` when none arrived within `timeout`.
    fn receive(&mut self, timeout: Duration) -> Result<Option<[u8; 8]>, LinkError>;
    /// The link in words for messages, such as `TRC1000 unit 0 (bus 1 address 4)`.
    fn describe(&self) -> String;
}

pub mod far_end;
pub mod fd;
pub mod holders;
pub mod line;
pub mod memory;
pub mod serial;
pub mod tcp;
pub mod usb;

impl<T: ByteLink + ?Sized> ByteLink for Box<T> {
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), LinkError> {
        (**self).write_all(bytes)
    }

    fn read(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, LinkError> {
        (**self).read(buf, timeout)
    }

    fn set_baud(&mut self, baud: u32) -> Result<(), LinkError> {
        (**self).set_baud(baud)
    }

    fn describe(&self) -> String {
        (**self).describe()
    }

    fn line(&mut self) -> Option<&mut LineState> {
        (**self).line()
    }

    fn watch(&self) -> Option<Watch> {
        (**self).watch()
    }
}

impl<T: PacketLink + ?Sized> PacketLink for Box<T> {
    fn send(&mut self, packet: &[u8; 8], timeout: Duration) -> Result<(), LinkError> {
        (**self).send(packet, timeout)
    }

    fn receive(&mut self, timeout: Duration) -> Result<Option<[u8; 8]>, LinkError> {
        (**self).receive(timeout)
    }

    fn describe(&self) -> String {
        (**self).describe()
    }
}
