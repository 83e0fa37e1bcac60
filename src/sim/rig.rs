//! The simulators of a rig (`--sim`, scenario tests, `verify`): the in-memory links the
//! runtime's drivers talk over, each to a simulated device that a test can unplug, slow or
//! garble (`runtime::devices::links`, `sim::faults::answer`), and the field side a test drives.

use crate::config::{C29uConfig, RigConfig};
use crate::link::memory::{MemoryByteLink, MemoryPacketLink};
use crate::link::{ByteLink, PacketLink};
use crate::protocol::c29u::baud_code;
use crate::runtime::devices::links::{Counted, Presence, TransactionCounter, Unpluggable};
use crate::runtime::devices::{open_devices_with, OpenError, Opened, SimDevice, SimLinks};
use crate::sim::c29u::{C29uModel, Eeprom, ModuleConfig};
use crate::sim::c29u_line::SimulatedC29u;
use crate::sim::faults::answer::{AnswerFaults, Faulty};
use crate::sim::trc1000::Trc1000Sim;
use crate::time::clock::SharedClock;
use std::sync::{Arc, Mutex};

/// Opens every device `config` names, simulators for all when `simulate` and for those it
/// marks simulated in any case (`runtime::devices::open_devices_with` over `Simulators`).
pub fn open_devices(
    config: &RigConfig,
    clock: &SharedClock,
    simulate: bool,
    count: &TransactionCounter,
) -> Result<Opened, OpenError> {
    open_devices_with(config, clock, simulate, count, &mut Simulators)
}

/// Opens links to in-memory simulators.
pub struct Simulators;

impl SimLinks for Simulators {
    fn trc(
        &mut self,
        name: &str,
        clock: &SharedClock,
        count: &TransactionCounter,
    ) -> (Box<dyn PacketLink>, SimDevice) {
        let board = Arc::new(Mutex::new(Trc1000Sim::new()));
        let presence = Presence::new();
        let faults = AnswerFaults::default();
        let link = MemoryPacketLink::new(
            Unpluggable::new(
                Faulty::new(Arc::clone(&board), faults.clone()),
                presence.clone(),
            )
            .with_clock(Arc::clone(clock)),
            format!("TRC1000 {name}"),
        )
        .with_clock(Arc::clone(clock))
        .deliver_with({
            let faults = faults.clone();
            move || faults.take_delivery()
        });
        (
            Box::new(Counted::new(link, Arc::clone(count))),
            SimDevice::Trc {
                board,
                presence,
                faults,
            },
        )
    }

    fn c29u(
        &mut self,
        name: &str,
        c: &C29uConfig,
        clock: &SharedClock,
        count: &TransactionCounter,
    ) -> (Box<dyn ByteLink>, SimDevice) {
        let eeprom = Eeprom {
            config: ModuleConfig {
                id: c.id,
                baud_code: baud_code(c.baud).unwrap_or(ModuleConfig::factory().baud_code),
                checksum: c.checksum,
                ..ModuleConfig::factory()
            },
            ..Eeprom::factory()
        };
        let module = SimulatedC29u::new(C29uModel::new(c.protocol, Arc::clone(clock), eeprom));
        let model = module.model();
        let presence = Presence::new();
        let faults = AnswerFaults::default();
        let link = MemoryByteLink::new(
            Unpluggable::new(Faulty::new(module, faults.clone()), presence.clone())
                .with_clock(Arc::clone(clock)),
            format!("TRP-C29U {name}"),
        )
        .with_clock(Arc::clone(clock))
        .delay_answers({
            let faults = faults.clone();
            move |_| faults.take_delivery().late
        });
        (
            Box::new(Counted::new(link, Arc::clone(count))),
            SimDevice::C29u {
                model,
                presence,
                faults,
            },
        )
    }
}
