//! Makes the rig's devices from rig.toml: real drivers over real links, or (`--sim`, scenario
//! tests) the same drivers over the links to simulators that the composition root opens
//! (`SimLinks`: the runtime builds no simulator).

use super::c29u::{ByteReopener, C29uDevice};
use super::links::{Counted, TransactionCounter};
use super::sim::{SimDevice, SimRig};
use super::trc::{PacketReopener, TrcDevice};
use super::{Device, DeviceError};
use crate::config::feeding::{feed_timing, TRC1000_TIMEOUT};
use crate::config::{C29uConfig, DeviceConfig, Port, RigConfig, Trc1000Address, Trc1000Config};
use crate::device::c29u::{open_port, share, C29u, C29uOptions, SharedLink};
use crate::device::trc1000::{Trc1000, Trc1000Error};
use crate::link::tcp::TcpLink;
use crate::link::usb::{UsbPacketLink, UsbTarget};
use crate::link::{ByteLink, PacketLink};
use crate::time::clock::SharedClock;
use std::collections::BTreeMap;
use std::sync::Arc;

/// A device that could not be opened.
#[derive(Debug, thiserror::Error)]
#[error("device {device}: {source}")]
pub struct OpenError {
    /// The device's name.
    pub device: String,
    /// Why.
    #[source]
    pub source: DeviceError,
}

/// The devices of a rig, and their simulators when simulated.
pub struct Opened {
    /// In name order.
    pub devices: Vec<Device>,
    /// The field side of the simulators (empty for real hardware).
    pub sim: SimRig,
}

/// Opens the links to simulated devices: made where a run is composed (`sim::rig`), so that
/// the runtime drives a simulator as it drives hardware, through a link.
pub trait SimLinks {
    /// A simulated TRC1000 called `name`: the link its driver talks over (every request
    /// counted in `count`: `links::Counted`), and its field side.
    fn trc(
        &mut self,
        name: &str,
        clock: &SharedClock,
        count: &TransactionCounter,
    ) -> (Box<dyn PacketLink>, SimDevice);
    /// A simulated TRP-C29U called `name`, set up as `config` has it: the link its drivers
    /// talk over (counted as `trc`'s), and its field side.
    fn c29u(
        &mut self,
        name: &str,
        config: &C29uConfig,
        clock: &SharedClock,
        count: &TransactionCounter,
    ) -> (Box<dyn ByteLink>, SimDevice);
}

/// Opens every device `config` names: over the links `sims` opens for all when `simulate`,
/// and for those it marks simulated (`RigConfig::is_simulated`) in any case. Every request is
/// counted in `count`.
pub fn open_devices_with(
    config: &RigConfig,
    clock: &SharedClock,
    simulate: bool,
    count: &TransactionCounter,
    sims: &mut dyn SimLinks,
) -> Result<Opened, OpenError> {
    let mut devices = Vec::new();
    let mut sim = SimRig::default();
    let mut lines: BTreeMap<String, SharedLink> = BTreeMap::new();
    for (name, device) in &config.devices {
        let simulate = simulate || config.is_simulated(name);
        let mut opened = match device {
            DeviceConfig::Trc1000(c) if simulate => {
                let (d, s) = simulated_trc(name, c, clock, count, sims);
                sim.insert(name, s);
                Device::Trc(Box::new(d))
            }
            DeviceConfig::Trc1000(c) => Device::Trc(Box::new(real_trc(name, c, clock, count)?)),
            DeviceConfig::C29u(c) if simulate => {
                let (d, s) = simulated_c29u(name, c, clock, count, sims)?;
                sim.insert(name, s);
                Device::C29u(Box::new(d))
            }
            DeviceConfig::C29u(c) => {
                Device::C29u(Box::new(real_c29u(name, c, clock, count, &mut lines)?))
            }
        };
        if let Device::C29u(d) = &mut opened {
            d.feed_timing = feed_timing(&config.devices, name);
        }
        devices.push(opened);
    }
    Ok(Opened { devices, sim })
}

fn open_error(device: &str, source: impl Into<DeviceError>) -> OpenError {
    OpenError {
        device: device.to_string(),
        source: source.into(),
    }
}

fn simulated_trc(
    name: &str,
    config: &Trc1000Config,
    clock: &SharedClock,
    count: &TransactionCounter,
    sims: &mut dyn SimLinks,
) -> (TrcDevice, SimDevice) {
    let (link, sim) = sims.trc(name, clock, count);
    let mut driver = Trc1000::with_clock(link, Arc::clone(clock));
    driver.set_timeout(TRC1000_TIMEOUT);
    (TrcDevice::new(name, config.clone(), driver, None), sim)
}

fn real_trc(
    name: &str,
    config: &Trc1000Config,
    clock: &SharedClock,
    count: &TransactionCounter,
) -> Result<TrcDevice, OpenError> {
    let target = match config.address {
        Trc1000Address::Unit(u) => UsbTarget::Unit(u),
        Trc1000Address::BusAddress { bus, address } => UsbTarget::BusAddress { bus, address },
    };
    let count = Arc::clone(count);
    let mut reopener: PacketReopener = Box::new(move || {
        let link = UsbPacketLink::open(target)?;
        Ok(Box::new(Counted::new(link, Arc::clone(&count))) as Box<dyn PacketLink>)
    });
    let link = reopener().map_err(|e| open_error(name, Trc1000Error::Link(e)))?;
    let mut driver = Trc1000::with_clock(link, Arc::clone(clock));
    driver.set_timeout(TRC1000_TIMEOUT);
    Ok(TrcDevice::new(name, config.clone(), driver, Some(reopener)))
}

/// The driver options a TRP-C29U entry of rig.toml asks for.
pub fn c29u_options(c: &C29uConfig) -> C29uOptions {
    C29uOptions {
        protocol: c.protocol,
        id: c.id,
        baud: c.baud,
        checksum: c.checksum,
        timeout: c.timeout,
        retries: u32::from(c.retries),
        di_active_low: c.di_active_low,
        frame_gap: c.frame_gap,
    }
}

fn drivers(
    name: &str,
    c: &C29uConfig,
    line: &SharedLink,
    clock: &SharedClock,
) -> Result<(C29u, C29u), OpenError> {
    let driver = C29u::new(Arc::clone(line), Arc::clone(clock), c29u_options(c))
        .map_err(|e| open_error(name, e))?;
    let probe = C29u::new(
        Arc::clone(line),
        Arc::clone(clock),
        C29uOptions {
            retries: 0,
            ..c29u_options(c)
        },
    )
    .map_err(|e| open_error(name, e))?;
    Ok((driver, probe))
}

fn simulated_c29u(
    name: &str,
    c: &C29uConfig,
    clock: &SharedClock,
    count: &TransactionCounter,
    sims: &mut dyn SimLinks,
) -> Result<(C29uDevice, SimDevice), OpenError> {
    let (link, sim) = sims.c29u(name, c, clock, count);
    let line = share(link);
    let (driver, probe) = drivers(name, c, &line, clock)?;
    Ok((
        C29uDevice::new(name, c.clone(), driver, probe, line, None),
        sim,
    ))
}

fn real_c29u(
    name: &str,
    c: &C29uConfig,
    clock: &SharedClock,
    count: &TransactionCounter,
    lines: &mut BTreeMap<String, SharedLink>,
) -> Result<C29uDevice, OpenError> {
    let port = c.port.to_string();
    let (baud, timeout) = (c.baud, c.timeout);
    let reopen_count = Arc::clone(count);
    let reopen_port = port.clone();
    let device_server = matches!(c.port, Port::Tcp { .. });
    let reopener: ByteReopener = Box::new(move || {
        // Tried once a second while the module is lost, with every other module waiting: a
        // device server gets the module's own timeout to answer (as much as an exchange, which
        // config::feeding counts), not the longer wait of the first connection.
        let link: Box<dyn ByteLink> = if device_server {
            Box::new(TcpLink::connect(&reopen_port, timeout)?)
        } else {
            open_port(&reopen_port, baud, timeout)?
        };
        Ok(Box::new(Counted::new(link, Arc::clone(&reopen_count))) as Box<dyn ByteLink>)
    });
    // Modules on one RS-485 line share one port (and take turns on it).
    let line = match lines.get(&port) {
        Some(line) => Arc::clone(line),
        None => {
            let link = open_port(&port, baud, timeout)
                .map_err(|e| open_error(name, crate::device::c29u::C29uError::Link(e)))?;
            let line = share(Box::new(Counted::new(link, Arc::clone(count))));
            lines.insert(port, Arc::clone(&line));
            line
        }
    };
    let (driver, probe) = drivers(name, c, &line, clock)?;
    Ok(C29uDevice::new(
        name,
        c.clone(),
        driver,
        probe,
        line,
        Some(reopener),
    ))
}
