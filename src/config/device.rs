//! The `[devices.NAME]` tables of rig.toml: one typed configuration per kind of device.

use super::error::ProblemKind;
use super::names::{self, PointNames, Points};
use super::reader::{bad, boolean, duration, integer_in, string, Reader, TableRef};
use super::script_may_change::{self, ScriptMayChange};
pub use crate::link::line::FrameGap;
use crate::link::line::MAX_FRAME_GAP;
use crate::protocol::c29u::{baud_code, BAUD_CODES};
pub use crate::protocol::c29u::{Protocol, WatchdogTimeout};
use crate::protocol::c29u_modbus::SLAVE_IDS;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt;
use std::path::PathBuf;
use std::time::Duration;
use toml::de::DeValue;

/// The configuration of one named device.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum DeviceConfig {
    /// A TRC1000 USB panel board (`kind = "trc1000"`).
    Trc1000(Trc1000Config),
    /// A TRP-C29U I/O module (`kind = "trp-c29u"`).
    C29u(C29uConfig),
}

impl DeviceConfig {
    /// The `kind` value that selects this device type.
    pub fn kind_name(&self) -> &'static str {
        match self {
            DeviceConfig::Trc1000(_) => KIND_TRC1000,
            DeviceConfig::C29u(_) => KIND_C29U,
        }
    }
}

const KIND_TRC1000: &str = "trc1000";
const KIND_C29U: &str = "trp-c29u";

/// A TRC1000 board and its safe state.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Trc1000Config {
    /// Which board: by DIP-switch unit (default unit 0) or by USB bus and address.
    pub address: Trc1000Address,
    /// Relay position written when outputs must go safe; `None` (the default) leaves the
    /// selector where it is, since every position selects something.
    pub safe_relay: Option<u8>,
    /// What rig.toml calls its switches, rotaries and relay positions (`names`).
    pub names: PointNames,
}

/// How to find a TRC1000 on the USB.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Trc1000Address {
    /// DIP-switch unit 0-3 (product ID 0x02AC + unit).
    Unit(u8),
    /// USB bus number and device address, for two boards that share a unit.
    BusAddress {
        /// USB bus number.
        bus: u8,
        /// Device address on that bus, 1-127.
        address: u8,
    },
}

/// A TRP-C29U module, its link, and its safe state.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct C29uConfig {
    /// Where the module is (required in rig.toml).
    pub port: Port,
    /// Which of the module's two protocols its DIP switch selects (default Modbus, the factory
    /// setting).
    pub protocol: Protocol,
    /// Module address: 1-247 for Modbus, 0-255 for ASCII (default 1, the factory setting).
    pub id: u8,
    /// Line speed, one of the module's rates of manual 8-2 (default 9600).
    pub baud: u32,
    /// ASCII checksums on (default off; Modbus RTU always has its CRC).
    pub checksum: bool,
    /// How long to wait for an answer (default 100 ms; `TIMEOUT_RANGE`).
    pub timeout: Duration,
    /// How many times to repeat a request that got no valid answer (default 2, at most 10).
    pub retries: u8,
    /// Host watchdog the runner enables and feeds (default none).
    pub watchdog: Option<WatchdogTimeout>,
    /// DO byte for the safe state, also the module's own watchdog safe value (default 0x00).
    pub safe_value: u8,
    /// DO byte the module loads at power on; `None` (the default) leaves the module's as is.
    pub power_on_value: Option<u8>,
    /// Whether an energized input reads as a 0 bit on the wire (default true, as manual 8-11 and
    /// 10-17 show: docs/trp-c29u-protocol.md, 'DI polarity').
    pub di_active_low: bool,
    /// Silence kept on a serial line before each request (default auto: the protocol's rule).
    pub frame_gap: FrameGap,
    /// Which of the fail-safe settings given here the script may change (`script_may_change`).
    pub script_may_change: ScriptMayChange,
    /// What rig.toml calls its channels (`names`).
    pub names: PointNames,
}

/// The answer timeouts rig.toml accepts: an answer at 1200 baud with its request takes a
/// quarter of a second, and every wait on a silent module delays a SIGTERM's safe-state write
/// and the watchdog feed by timeout x attempts, so more than a second helps nobody.
pub const TIMEOUT_RANGE: std::ops::RangeInclusive<Duration> =
    Duration::from_millis(1)..=Duration::from_secs(1);

impl C29uConfig {
    /// A module at `port` with every other setting at its default.
    pub fn with_defaults(port: Port) -> Self {
        Self {
            port,
            protocol: Protocol::Modbus,
            id: 1,
            baud: 9600,
            checksum: false,
            timeout: Duration::from_millis(100),
            retries: 2,
            watchdog: None,
            safe_value: 0x00,
            power_on_value: None,
            di_active_low: true,
            frame_gap: FrameGap::Auto,
            script_may_change: ScriptMayChange::ALL,
            names: PointNames::default(),
        }
    }
}

/// Where a TRP-C29U is reached.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Port {
    /// A serial device (`/dev/ttyUSB0`).
    Serial(PathBuf),
    /// A serial device server (`tcp://host:port`).
    Tcp {
        /// Host name or address (IPv6 without brackets).
        host: String,
        /// TCP port.
        port: u16,
    },
    /// The in-memory simulator (only from `RigConfig::simulated_default`).
    Simulated,
}

impl fmt::Display for Port {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Port::Serial(path) => write!(f, "{}", path.display()),
            Port::Tcp { host, port } if host.contains(':') => write!(f, "tcp://[{host}]:{port}"),
            Port::Tcp { host, port } => write!(f, "tcp://{host}:{port}"),
            Port::Simulated => f.write_str("simulator"),
        }
    }
}

const DEVICE_KEYS_TRC1000: &[&str] = &["kind", "unit", "device", "safe_relay", "sim", names::KEY];
const DEVICE_KEYS_C29U: &[&str] = &[
    "kind",
    "port",
    "protocol",
    "id",
    "baud",
    "checksum",
    "timeout",
    "retries",
    "watchdog",
    "safe_value",
    "power_on_value",
    "di_active_low",
    "frame_gap",
    script_may_change::KEY,
    "sim",
    names::KEY,
];

/// Whether `name` can name a device: an identifier of ASCII letters, digits and `_`.
pub fn is_device_name(name: &str) -> bool {
    let mut chars = name.chars();
    matches!(chars.next(), Some(c) if c.is_ascii_alphabetic() || c == '_')
        && chars.all(|c| c.is_ascii_alphanumeric() || c == '_')
        && name.len() <= 64
}

/// Reads the `[devices]` table.
/// Reads `[devices.NAME]` tables: the devices by name, and the names of those marked
/// `sim = true` (simulated while the others are real).
pub(super) fn read_devices(
    r: &mut Reader<'_>,
    devices: &TableRef<'_, '_>,
) -> (BTreeMap<String, DeviceConfig>, BTreeSet<String>) {
    let mut out = BTreeMap::new();
    let mut simulated = BTreeSet::new();
    for (key, value) in devices.table.iter() {
        let name: &str = key.get_ref();
        if !is_device_name(name) {
            r.report(
                &key.span(),
                devices.path.clone(),
                ProblemKind::BadValue {
                    value: format!("{name:?}"),
                    reason: "is not a usable device name; use letters, digits and _, \
                             starting with a letter or _ (at most 64)"
                        .into(),
                },
            );
            continue;
        }
        let DeValue::Table(table) = value.get_ref() else {
            r.report(
                &value.span(),
                devices.key_path(name),
                ProblemKind::WrongType {
                    expected: "a table ([devices.NAME])",
                    found: super::reader::type_name(value.get_ref()),
                },
            );
            continue;
        };
        let t = TableRef {
            path: devices.key_path(name),
            span: value.span(),
            table,
        };
        let sim = r.read(&t, "sim", boolean).unwrap_or(false);
        if sim {
            simulated.insert(name.to_string());
        }
        if let Some(device) = read_device(r, &t, sim) {
            out.insert(name.to_string(), device);
        }
    }
    (out, simulated)
}

fn read_device(r: &mut Reader<'_>, t: &TableRef<'_, '_>, sim: bool) -> Option<DeviceConfig> {
    let Some(kind) = r.read(t, "kind", |v| {
        let s = string(v)?;
        match s.as_str() {
            KIND_TRC1000 | KIND_C29U => Ok(s),
            _ => Err(bad(
                v,
                r#"is not a device kind; use "trc1000" or "trp-c29u""#,
            )),
        }
    }) else {
        if t.get("kind").is_none() {
            r.missing(t, "kind", r#"give kind = "trc1000" or kind = "trp-c29u""#);
        }
        return None;
    };
    if kind == KIND_TRC1000 {
        r.check_keys(t, DEVICE_KEYS_TRC1000);
        Some(DeviceConfig::Trc1000(read_trc1000(r, t)))
    } else {
        r.check_keys(t, DEVICE_KEYS_C29U);
        read_c29u(r, t, sim).map(DeviceConfig::C29u)
    }
}

fn read_trc1000(r: &mut Reader<'_>, t: &TableRef<'_, '_>) -> Trc1000Config {
    let unit = r.read(t, "unit", |v| {
        integer_in(v, 0..=3, "is not a unit; use 0-3")
    });
    let by_bus = r.read(t, "device", bus_address);
    if let (Some(_), Some(device)) = (t.get("unit"), t.get("device")) {
        r.report(
            &device.span(),
            t.key_path("device"),
            ProblemKind::Conflict { other: "unit" },
        );
    }
    let address = match (by_bus, unit) {
        (Some((bus, address)), _) => Trc1000Address::BusAddress { bus, address },
        (None, unit) => Trc1000Address::Unit(unit.and_then(|u| u8::try_from(u).ok()).unwrap_or(0)),
    };
    let safe_relay = r
        .read(t, "safe_relay", |v| {
            integer_in(v, 0..=7, "is not a relay; use 0-7")
        })
        .and_then(|n| u8::try_from(n).ok());
    Trc1000Config {
        address,
        safe_relay,
        names: names::read(r, t, Points::Trc1000),
    }
}

/// `"BUS:ADDRESS"`, as `lsusb` shows them.
fn bus_address(v: &DeValue<'_>) -> Result<(u8, u8), ProblemKind> {
    let s = string(v)?;
    let parsed = s.split_once(':').and_then(|(bus, address)| {
        let bus: u8 = bus.trim().parse().ok()?;
        let address: u8 = address.trim().parse().ok()?;
        (1..=127).contains(&address).then_some((bus, address))
    });
    parsed.ok_or_else(|| {
        bad(
            v,
            r#"is not a USB bus and address; use "BUS:ADDRESS" as lsusb shows them ("1:4"), address 1-127"#,
        )
    })
}

fn read_c29u(r: &mut Reader<'_>, t: &TableRef<'_, '_>, sim: bool) -> Option<C29uConfig> {
    let port = r.read(t, "port", port);
    // A simulated module needs no port (one given is kept for when `sim` is taken out).
    if t.get("port").is_none() && !sim {
        r.missing(
            t,
            "port",
            r#"give the serial port ("/dev/ttyUSB0") or a device server ("tcp://host:port")"#,
        );
    }
    let mut c = C29uConfig::with_defaults(Port::Simulated);
    c.protocol = r.read(t, "protocol", protocol).unwrap_or(c.protocol);
    let proto = c.protocol;
    if let Some(id) = r.read(t, "id", |v| match proto {
        Protocol::Modbus => integer_in(
            v,
            i64::from(*SLAVE_IDS.start())..=i64::from(*SLAVE_IDS.end()),
            "is not a Modbus id; use 1-247",
        ),
        Protocol::Ascii => integer_in(v, 0..=255, "is not an ASCII id; use 0-255"),
    }) {
        c.id = u8::try_from(id).unwrap_or(c.id);
    }
    if let Some(baud) = r.read(t, "baud", baud) {
        c.baud = baud;
    }
    c.checksum = r
        .read(t, "checksum", |v| match (boolean(v)?, proto) {
            (true, Protocol::Modbus) => Err(bad(
                v,
                "is for the ascii protocol only; Modbus RTU frames always carry a CRC",
            )),
            (on, _) => Ok(on),
        })
        .unwrap_or(c.checksum);
    c.timeout = r
        .read(t, "timeout", |v| match duration(v)? {
            d if TIMEOUT_RANGE.contains(&d) => Ok(d),
            _ => Err(bad(
                v,
                "is not a timeout; use 1ms to 1s (a silent module costs this per try, \
                 and a SIGTERM waits for it)",
            )),
        })
        .unwrap_or(c.timeout);
    if let Some(n) = r.read(t, "retries", |v| {
        integer_in(v, 0..=10, "is not a retry count; use 0-10")
    }) {
        c.retries = u8::try_from(n).unwrap_or(c.retries);
    }
    c.watchdog = r.read(t, "watchdog", watchdog).unwrap_or(c.watchdog);
    if let Some(n) = r.read(t, "safe_value", byte) {
        c.safe_value = n;
    }
    let (proto, safe, id, checksum) = (c.protocol, c.safe_value, c.id, c.checksum);
    c.power_on_value = r
        .read(t, "power_on_value", |v| match byte(v)? {
            // Storing it would drive the outputs to it: refused before anything starts.
            n if proto == Protocol::Ascii && n != safe => {
                let port = port.as_ref().map_or("PORT".to_string(), Port::to_string);
                let checksum = if checksum { " --checksum" } else { "" };
                Err(bad(
                    v,
                    format!(
                        "differs from safe_value {safe:#04x}: an ASCII module stores only its \
                         current outputs as its power-on value (manual 8-24), so the runner \
                         would have to drive the outputs to it; store it once by hand, when the \
                         outputs may take that value (`rigscript c29 --port {port} --protocol \
                         ascii --id {id}{checksum} power-on-value {n:#04x} --drive-outputs`), \
                         and leave it out of rig.toml, or make it equal to safe_value"
                    ),
                ))
            }
            n => Ok(n),
        })
        .or(c.power_on_value);
    c.di_active_low = r
        .read(t, "di_active_low", boolean)
        .unwrap_or(c.di_active_low);
    c.frame_gap = r.read(t, "frame_gap", frame_gap).unwrap_or(c.frame_gap);
    let listed = r.read(t, script_may_change::KEY, script_may_change::read);
    c.script_may_change = ScriptMayChange::of(t, &listed.unwrap_or_default());
    c.names = names::read(r, t, Points::C29u);
    let port = if sim {
        Some(port.unwrap_or(Port::Simulated))
    } else {
        port
    };
    port.map(|port| C29uConfig { port, ..c })
}

fn port(v: &DeValue<'_>) -> Result<Port, ProblemKind> {
    let s = string(v)?;
    let not_a_port = || {
        bad(
            v,
            r#"is not a port; use a serial device ("/dev/ttyUSB0") or "tcp://host:port""#,
        )
    };
    if let Some(rest) = s.strip_prefix("tcp://") {
        let (host, port) = rest.rsplit_once(':').ok_or_else(not_a_port)?;
        let host = host
            .strip_prefix('[')
            .and_then(|h| h.strip_suffix(']'))
            .unwrap_or(host);
        let port: u16 = port.parse().map_err(|_| not_a_port())?;
        if host.is_empty() || port == 0 || host.contains('/') {
            return Err(not_a_port());
        }
        return Ok(Port::Tcp {
            host: host.to_string(),
            port,
        });
    }
    if s.trim().is_empty() || s.contains("://") {
        return Err(not_a_port());
    }
    Ok(Port::Serial(PathBuf::from(s)))
}

fn protocol(v: &DeValue<'_>) -> Result<Protocol, ProblemKind> {
    match string(v)?.as_str() {
        "modbus" => Ok(Protocol::Modbus),
        "ascii" => Ok(Protocol::Ascii),
        _ => Err(bad(v, r#"is not a protocol; use "modbus" or "ascii""#)),
    }
}

fn baud(v: &DeValue<'_>) -> Result<u32, ProblemKind> {
    let rates: Vec<String> = BAUD_CODES.iter().map(|(_, b)| b.to_string()).collect();
    let use_rates = format!(
        "is not a baud rate of the module; use one of {}",
        rates.join(", ")
    );
    let n = integer_in(v, 0..=i64::from(u32::MAX), &use_rates)?;
    u32::try_from(n)
        .ok()
        .filter(|rate| baud_code(*rate).is_some())
        .ok_or_else(|| bad(v, use_rates))
}

fn frame_gap(v: &DeValue<'_>) -> Result<FrameGap, ProblemKind> {
    let not_a_gap = || {
        bad(
            v,
            r#"is not a frame gap; use "auto" (the protocol's silence) or a duration up to 1s"#,
        )
    };
    let d = match v {
        DeValue::String(s) if s.as_ref() == "auto" => return Ok(FrameGap::Auto),
        DeValue::String(_) => duration(v).map_err(|_| not_a_gap())?,
        // A bare number gets the duration reader's advice (write a unit).
        _ => duration(v)?,
    };
    if d <= MAX_FRAME_GAP {
        Ok(FrameGap::Fixed(d))
    } else {
        Err(not_a_gap())
    }
}

fn byte(v: &DeValue<'_>) -> Result<u8, ProblemKind> {
    let n = integer_in(
        v,
        0..=255,
        "is not a DO byte; use 0-255 (0x00-0xFF, 0b00000000-0b11111111)",
    )?;
    u8::try_from(n).map_err(|_| bad(v, "is not a DO byte"))
}

fn watchdog(v: &DeValue<'_>) -> Result<Option<WatchdogTimeout>, ProblemKind> {
    if let DeValue::String(s) = v {
        if s.as_ref() == "off" {
            return Ok(None);
        }
    }
    let not_a_watchdog = || {
        bad(
            v,
            r#"is not a watchdog time; use 0.1s to 25.5s in steps of 0.1s, or "off""#,
        )
    };
    let d = match duration(v) {
        Ok(d) => d,
        Err(ProblemKind::BadValue { .. }) => return Err(not_a_watchdog()),
        Err(other) => return Err(other),
    };
    if d.is_zero() {
        return Ok(None);
    }
    WatchdogTimeout::from_duration(d)
        .map(Some)
        .ok_or_else(not_a_watchdog)
}

#[cfg(test)]
mod tests {
    use super::super::RigConfig;
    use super::*;

    fn io(extra: &str) -> Result<C29uConfig, String> {
        let text = format!("[devices.io]\nkind = \"trp-c29u\"\nport = \"/dev/ttyUSB0\"\n{extra}\n");
        let mut c = RigConfig::parse(&text, "rig.toml").map_err(|e| e.to_string())?;
        match c.devices.remove("io") {
            Some(DeviceConfig::C29u(io)) => Ok(io),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn frame_gap_is_auto_unless_given() {
        assert_eq!(io("").unwrap().frame_gap, FrameGap::Auto);
        assert_eq!(
            io("frame_gap = \"auto\"").unwrap().frame_gap,
            FrameGap::Auto
        );
        assert_eq!(
            io("frame_gap = \"5ms\"").unwrap().frame_gap,
            FrameGap::Fixed(Duration::from_millis(5))
        );
        assert_eq!(
            io("frame_gap = \"0s\"").unwrap().frame_gap,
            FrameGap::Fixed(Duration::ZERO)
        );
        for bad in ["frame_gap = \"2s\"", "frame_gap = \"often\""] {
            let e = io(bad).unwrap_err();
            assert!(e.contains("devices.io.frame_gap"), "{e}");
            assert!(e.contains("\"auto\""), "{e}");
        }
        assert!(io("frame_gap = 5").unwrap_err().contains("has no unit"));
    }

    #[test]
    fn absurd_timeouts_are_refused_with_the_accepted_range() {
        assert_eq!(
            io("timeout = \"1s\"").unwrap().timeout,
            Duration::from_secs(1)
        );
        assert_eq!(
            io("timeout = \"1ms\"").unwrap().timeout,
            Duration::from_millis(1)
        );
        for bad in [
            "timeout = \"1000000h\"",
            "timeout = \"1.001s\"",
            "timeout = \"0s\"",
            "timeout = \"500us\"",
        ] {
            let e = io(bad).unwrap_err();
            assert!(e.contains("use 1ms to 1s"), "{bad}: {e}");
        }
    }
}
