//! Runs one case the way `rigscript run` runs a script (`RigBuilder::start`, then
//! `Runner::run`), in virtual time: the real drivers talk to simulated modules through
//! `FaultyLink`s, the faults of the schedule come due on an `EventClock`, and afterwards the
//! modules are left alone long enough for their own watchdogs to act. What happened is
//! collected for the oracle; nothing here judges it.

use super::case::{Case, InjectedFault, Proto};
use super::{probe, render};
use rigscript::config::{DeviceConfig, RigConfig, DEFAULT_MEMORY};
use rigscript::device::c29u::{share, C29u, C29uOptions, SharedLink};
use rigscript::runtime::devices::links::{Counted, Presence, TransactionCounter};
use rigscript::runtime::devices::{C29uDevice, Device, OpenError, Opened, SimDevice, SimRig};
use rigscript::script::rig::RigError;
use rigscript::sim::c29u::{
    C29uModel as Model, Eeprom, ModuleConfig, OutputFault, Protocol, WatchdogStatus,
};
use rigscript::sim::c29u_line::{lock, MultiDrop, SharedModel, SimulatedC29u};
use rigscript::sim::faults::answer::AnswerFaults;
use rigscript::sim::faults::{Connection, EventClock, FaultHit, FaultPlan, FaultyLink, LinkFault};
use rigscript::time::clock::{Clock, SharedClock, VirtualClock};
use rigscript::time::zone::Zone;
use rigscript::RigBuilder;
use std::collections::BTreeMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::rc::Rc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// The signal number SIGTERM and kill -9 leave in the stop flag (SIGTERM).
const SIGTERM: usize = 15;

/// Entries kept in each module's output history (a case has far fewer).
pub const HISTORY_CAPACITY: usize = 200_000;

/// How long the modules are left alone after the run (longer than any watchdog).
pub const AFTER_END_WAIT: Duration = Duration::from_secs(26);

/// The panic the search raises to end a run that does not end in time.
pub const HANG_MARKER: &str = "fault search: the run did not end in time";

/// The panic the search raises to end a run whose memory only grows.
pub const MEMORY_MARKER: &str = "fault search: script memory past the cap";

/// The panic the search raises to end a run whose work only grows.
pub const WORK_MARKER: &str = "fault search: the runner read the clock past the cap";

/// Clock reads in one case that count as work without bound (a case of normal work reads it a
/// few hundred thousand times at most): deterministic, unlike a time limit.
pub const CLOCK_READS_CAP: u64 = 30_000_000;

/// Heap growth (bytes) during one case that counts as unbounded; `FAULT_SEARCH_MEMORY_MB`
/// overrides it. It stays above the runner's own script memory limit (`[limits] memory`, the
/// default: the cases do not set it), so a script that only grows meets that limit first, as
/// it would in a real run, and the cap only catches memory the limit does not bound.
pub fn memory_cap() -> i64 {
    let mb = std::env::var("FAULT_SEARCH_MEMORY_MB")
        .ok()
        .and_then(|v| v.parse::<i64>().ok())
        .unwrap_or(512);
    let limit_mb = i64::try_from(DEFAULT_MEMORY >> 20).unwrap_or(i64::MAX);
    assert!(
        mb > limit_mb,
        "FAULT_SEARCH_MEMORY_MB={mb} is not above the runner's script memory limit ({limit_mb} \
         MiB), which must stop a growing script first; use more than {limit_mb}"
    );
    mb.saturating_mul(1 << 20)
}

/// One simulated module and the entries of rig.toml that name it.
pub struct ModuleView {
    /// Its line.
    pub line: u8,
    /// Its ID.
    pub id: u8,
    /// The model.
    pub model: SharedModel,
    /// The entries (indices into the rig's modules) that name it.
    pub entries: Vec<usize>,
    /// The DI byte the field put on it, from time zero.
    pub inputs: Vec<(Duration, u8)>,
}

/// What a module showed at a moment.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ModuleState {
    /// DO byte.
    pub outputs: u8,
    /// Stored safe value.
    pub safe_value: u8,
    /// Host watchdog.
    pub watchdog: WatchdogStatus,
}

/// How the run ended.
#[derive(Debug, Clone)]
pub enum End {
    /// rig.toml was refused (nothing ran).
    ConfigRefused(String),
    /// `RigBuilder::start` failed.
    StartFailed {
        /// Its exit status.
        status: i32,
        /// Its message.
        message: String,
    },
    /// `run` returned.
    Ran {
        /// The exit status.
        status: i32,
        /// The log.
        log: Vec<String>,
        /// The records (`record("ioN", ioN.inputs)`).
        records: Vec<serde_json::Value>,
        /// Ticks the loop ran.
        ticks: u64,
    },
    /// A panic left the runner (the messages are in `Run::panics`).
    Panicked,
}

/// Everything a case did, for the oracle.
pub struct Run {
    /// How it ended.
    pub end: End,
    /// When `run` returned (or the panic left it).
    pub ended_at: Duration,
    /// When SIGTERM was delivered.
    pub sigterm_at: Option<Duration>,
    /// When the runner was killed.
    pub killed_at: Option<Duration>,
    /// The run was ended by the search for not ending in time.
    pub hang: bool,
    /// The run was ended by the search when its heap grew past the cap (bytes grown).
    pub memory: Option<i64>,
    /// The run was ended by the search when it read the clock `CLOCK_READS_CAP` times.
    pub runaway: bool,
    /// Panics raised during the case (the search's own markers included).
    pub panics: Vec<String>,
    /// The simulated modules.
    pub modules: Vec<ModuleView>,
    /// Each line's state at the end of the run.
    pub lines_at_end: BTreeMap<u8, Connection>,
    /// The answers each line's answer faults acted on, and when.
    pub hits: BTreeMap<u8, Vec<FaultHit>>,
    /// Each module at the end of the run.
    pub at_end: Vec<ModuleState>,
    /// Each module after `AFTER_END_WAIT` on its own.
    pub after_wait: Vec<ModuleState>,
    /// The deadline past which the run counted as hung.
    pub bound: Duration,
}

impl Run {
    /// The module an entry names.
    pub fn module_of(&self, entry: usize) -> Option<usize> {
        self.modules.iter().position(|m| m.entries.contains(&entry))
    }
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn protocol(p: Proto) -> Protocol {
    match p {
        Proto::Modbus => Protocol::Modbus,
        Proto::Ascii => Protocol::Ascii,
    }
}

/// The latest time the run may end at: the first end asked for (`--for`, SIGTERM, kill) plus
/// what the end and the faults may fairly take.
fn bound(case: &Case) -> Duration {
    let r = &case.rig;
    let mut end = ms(r.run_for_ms);
    let mut slow = Duration::ZERO;
    for (at, f) in &case.faults {
        match f {
            InjectedFault::Sigterm | InjectedFault::Kill => end = end.min(ms(*at)),
            InjectedFault::Freeze { ms: d }
            | InjectedFault::LinkStall { ms: d, .. }
            | InjectedFault::Late { ms: d, .. } => {
                slow += ms(*d);
            }
            _ => {}
        }
    }
    let exchanges: Duration = r
        .modules
        .iter()
        .map(|m| ms(m.timeout_ms.min(10_000)) * (u32::from(m.retries) + 1) * 16)
        .sum();
    end + slow + exchanges + ms(3_000 + 2 * r.period_ms)
}

/// Runs `case`; panics only if the search itself is wrong (a script that does not compile).
pub fn run(case: &Case) -> Run {
    let config = match RigConfig::parse(&render::rig_toml(case), "rig.toml") {
        Ok(c) => c,
        Err(e) => return refused(e.to_string()),
    };
    let source = render::script(case);
    let origin = chrono::DateTime::parse_from_rfc3339("2026-01-05T00:00:00Z")
        .map(|t| t.to_utc())
        .unwrap_or_default();
    let time = VirtualClock::new(origin);
    let clock = Arc::new(EventClock::new(time.clone()));
    let shared: SharedClock = clock.clone();

    let plans: BTreeMap<u8, FaultPlan> = case
        .lines()
        .into_iter()
        .map(|l| (l, FaultPlan::new()))
        .collect();
    let mut modules: Vec<ModuleView> = Vec::new();
    let mut buses: BTreeMap<u8, MultiDrop> = BTreeMap::new();
    for (i, m) in case.rig.modules.iter().enumerate() {
        if let Some(v) = modules
            .iter_mut()
            .find(|v| v.line == m.line && v.id == m.id)
        {
            v.entries.push(i);
            continue;
        }
        let factory = Eeprom::factory();
        let eeprom = Eeprom {
            config: ModuleConfig {
                id: m.id,
                ..ModuleConfig::factory()
            },
            safe_value: if m.fresh { factory.safe_value } else { m.safe },
            power_on_value: match (m.fresh, m.power_on) {
                (false, Some(p)) => p,
                _ => factory.power_on_value,
            },
            ..factory
        };
        let mut model = Model::new(protocol(m.protocol), Arc::clone(&shared), eeprom);
        model.record_outputs(HISTORY_CAPACITY);
        let sim = SimulatedC29u::new(model);
        modules.push(ModuleView {
            line: m.line,
            id: m.id,
            model: sim.model(),
            entries: vec![i],
            inputs: vec![(Duration::ZERO, 0)],
        });
        buses.entry(m.line).or_default().attach(Box::new(sim));
    }

    let stop_flag = Arc::new(AtomicUsize::new(0));
    let sigterm_at = Arc::new(Mutex::new(None));
    let killed_at = Arc::new(Mutex::new(None));
    let hang = Arc::new(AtomicBool::new(false));
    let memory = Arc::new(Mutex::new(None));
    schedule(
        case,
        &clock,
        &plans,
        &mut modules,
        &stop_flag,
        &sigterm_at,
        &killed_at,
    );
    for m in &mut modules {
        m.inputs.sort_by_key(|(t, _)| *t);
    }
    let bound = bound(case);
    {
        let hang = Arc::clone(&hang);
        clock.at(bound, move |_| {
            hang.store(true, Ordering::SeqCst);
            panic!("{HANG_MARKER}");
        });
    }

    probe::begin_case();
    let base = probe::live_bytes();
    let runaway = Arc::new(AtomicBool::new(false));
    {
        let (memory, runaway) = (Arc::clone(&memory), Arc::clone(&runaway));
        let cap = memory_cap();
        let mut reads = 0u64;
        clock.watch(move |_| {
            reads += 1;
            if reads == CLOCK_READS_CAP {
                runaway.store(true, Ordering::SeqCst);
                panic!("{WORK_MARKER}");
            }
            let grown = probe::live_bytes() - base;
            let mut m = memory.lock().unwrap_or_else(|e| e.into_inner());
            if grown > cap && m.is_none() {
                *m = Some(grown);
                drop(m);
                panic!("{MEMORY_MARKER}");
            }
        });
    }
    let setup = RigBuilder::from_config(config)
        .simulated()
        .clock(Arc::clone(&shared))
        .zone(Zone::utc())
        .run_for(ms(case.rig.run_for_ms))
        .log_to_stderr(false)
        .keep_log()
        .stop_flag(stop_flag)
        .open_with(opener(buses, plans.clone(), &modules));
    let started = catch_unwind(AssertUnwindSafe(|| {
        setup.start(&source, "case.rhai").map_err(Box::new)
    }));
    let end = match started {
        Ok(Err(e)) if matches!(*e, RigError::Script(_)) => {
            panic!("the fault search wrote a script that does not compile: {e}\n{source}")
        }
        Ok(Err(e)) => End::StartFailed {
            status: e.status(),
            message: e.to_string(),
        },
        Ok(Ok(mut rig)) => {
            let rt = Rc::clone(rig.runner.runtime());
            let ran = catch_unwind(AssertUnwindSafe(|| rig.runner.run()));
            let ticks = rig.runner.stats().ticks;
            drop(rig);
            let mut r = rt.borrow_mut();
            let end = match ran {
                Ok(status) => End::Ran {
                    status,
                    log: r.log_lines().to_vec(),
                    records: r.records_kept().to_vec(),
                    ticks,
                },
                Err(_) => End::Panicked,
            };
            // Handlers hold the script's values, device handles among them, and those hold the
            // runtime: let them go, or every case would keep its runtime alive to the end.
            r.reset_program();
            end
        }
        Err(_) => End::Panicked,
    };
    let panics = probe::end_case();
    let ended_at = clock.now();
    clock.clear();

    let at_end = states(&modules);
    let lines_at_end: BTreeMap<u8, Connection> = plans
        .iter()
        .map(|(line, plan)| (*line, plan.state_at(ended_at)))
        .collect();
    let hits = plans
        .iter()
        .map(|(line, plan)| (*line, plan.hits()))
        .collect();
    // Left alone: unplugged adapters go back in (their modules boot), and time passes.
    for (line, state) in &lines_at_end {
        if *state == Connection::Disconnected {
            for m in modules.iter().filter(|m| m.line == *line) {
                lock(&m.model).power_cycle();
            }
        }
    }
    time.advance(AFTER_END_WAIT);
    let after_wait = states(&modules);

    let memory = *memory.lock().unwrap_or_else(|e| e.into_inner());
    let sigterm_at = *sigterm_at.lock().unwrap_or_else(|e| e.into_inner());
    let killed_at = *killed_at.lock().unwrap_or_else(|e| e.into_inner());
    Run {
        end,
        ended_at,
        sigterm_at,
        killed_at,
        hang: hang.load(Ordering::SeqCst),
        memory,
        runaway: runaway.load(Ordering::SeqCst),
        panics,
        modules,
        lines_at_end,
        hits,
        at_end,
        after_wait,
        bound,
    }
}

fn refused(message: String) -> Run {
    Run {
        end: End::ConfigRefused(message),
        ended_at: Duration::ZERO,
        sigterm_at: None,
        killed_at: None,
        hang: false,
        memory: None,
        runaway: false,
        panics: Vec::new(),
        modules: Vec::new(),
        lines_at_end: BTreeMap::new(),
        hits: BTreeMap::new(),
        at_end: Vec::new(),
        after_wait: Vec::new(),
        bound: Duration::ZERO,
    }
}

/// Each module as it is now (its watchdog brought up to date first).
fn states(modules: &[ModuleView]) -> Vec<ModuleState> {
    modules
        .iter()
        .map(|m| {
            let mut model = lock(&m.model);
            let watchdog = model.watchdog();
            ModuleState {
                outputs: model.outputs(),
                safe_value: model.safe_value(),
                watchdog,
            }
        })
        .collect()
}

/// The plan's fault for one of the case's answer faults, with the line (as the case numbers
/// it) whose answers it acts on.
pub fn answer_fault(fault: InjectedFault) -> Option<(u8, LinkFault)> {
    match fault {
        InjectedFault::Drop { line, answers } => Some((line, LinkFault::Drop { answers })),
        InjectedFault::Flip { line, at, xor } => Some((line, LinkFault::Flip { at, xor })),
        InjectedFault::Late { line, ms: d } => Some((line, LinkFault::Late(ms(d)))),
        _ => None,
    }
}

/// Puts the case's faults on the plans and the clock.
fn schedule(
    case: &Case,
    clock: &EventClock,
    plans: &BTreeMap<u8, FaultPlan>,
    modules: &mut [ModuleView],
    stop_flag: &Arc<AtomicUsize>,
    sigterm_at: &Arc<Mutex<Option<Duration>>>,
    killed_at: &Arc<Mutex<Option<Duration>>>,
) {
    let plan = |line: u8| plans.get(&case.line(line)).cloned().unwrap_or_default();
    let module_of = |modules: &[ModuleView], dev: u8| {
        let entry = case.entry(dev);
        modules.iter().position(|m| m.entries.contains(&entry))
    };
    for &(at, fault) in &case.faults {
        let t = ms(at);
        match fault {
            InjectedFault::Input { dev, value } => {
                if let Some(i) = module_of(modules, dev) {
                    let model = Arc::clone(&modules[i].model);
                    modules[i].inputs.push((t, value));
                    clock.at(t, move |_| lock(&model).set_inputs(value));
                }
            }
            InjectedFault::Sigterm => {
                let (flag, when) = (Arc::clone(stop_flag), Arc::clone(sigterm_at));
                clock.at(t, move |c| {
                    let mut w = when.lock().unwrap_or_else(|e| e.into_inner());
                    w.get_or_insert(c.now());
                    flag.store(SIGTERM, Ordering::SeqCst);
                });
            }
            InjectedFault::Kill => {
                let (flag, when) = (Arc::clone(stop_flag), Arc::clone(killed_at));
                let all: Vec<FaultPlan> = plans.values().cloned().collect();
                clock.at(t, move |c| {
                    let mut w = when.lock().unwrap_or_else(|e| e.into_inner());
                    w.get_or_insert(c.now());
                    for p in &all {
                        p.cut_off();
                    }
                    // What is left of the runner is stopped; nothing it does arrives.
                    flag.store(SIGTERM, Ordering::SeqCst);
                });
            }
            InjectedFault::Drop { .. }
            | InjectedFault::Flip { .. }
            | InjectedFault::Late { .. } => {
                if let Some((line, f)) = answer_fault(fault) {
                    plan(line).add(t, f);
                }
            }
            InjectedFault::LinkStall { line, ms: d } => plan(line).add(t, LinkFault::Stall(ms(d))),
            InjectedFault::Silence { line, ms: d } => plan(line).add(t, LinkFault::Silence(ms(d))),
            InjectedFault::Unplug { line, ms: d } => {
                plan(line).add(t, LinkFault::Disconnect(ms(d)));
                let on_line: Vec<SharedModel> = modules
                    .iter()
                    .filter(|m| m.line == case.line(line))
                    .map(|m| Arc::clone(&m.model))
                    .collect();
                // Plugged back in: the modules boot (before the host can see the line again).
                clock.at(t + ms(d), move |_| {
                    for m in &on_line {
                        lock(m).power_cycle();
                    }
                });
            }
            InjectedFault::ModuleReset { dev } => {
                if let Some(i) = module_of(modules, dev) {
                    let model = Arc::clone(&modules[i].model);
                    clock.at(t, move |_| lock(&model).power_cycle());
                }
            }
            InjectedFault::Swap {
                dev,
                safe,
                power_on,
            } => {
                if let Some(i) = module_of(modules, dev) {
                    let model = Arc::clone(&modules[i].model);
                    clock.at(t, move |_| {
                        let mut other = Eeprom::factory();
                        "OTHER".clone_into(&mut other.name);
                        other.safe_value = safe;
                        other.power_on_value = power_on;
                        let firmware = rigscript::protocol::c29u::FirmwareDate {
                            year: 14,
                            month: 9,
                            day: 1,
                        };
                        // A valid image by construction: the swap cannot fail.
                        let _ = lock(&model).swap(other, firmware);
                    });
                }
            }
            InjectedFault::OutputStage { dev, refuse, ms: d } => {
                if let Some(i) = module_of(modules, dev) {
                    let (on, off) = (Arc::clone(&modules[i].model), Arc::clone(&modules[i].model));
                    let fault = refuse.map_or(OutputFault::Ignore, OutputFault::Refuse);
                    clock.at(t, move |_| lock(&on).set_output_fault(Some(fault)));
                    clock.at(t + ms(d), move |_| lock(&off).set_output_fault(None));
                }
            }
            InjectedFault::Freeze { ms: d } => clock.at(t, move |c| c.advance(ms(d))),
            InjectedFault::Panic { line } => plan(line).add(t, LinkFault::Panic),
        }
    }
}

/// Opens the rig's entries as the real drivers over `FaultyLink`s to the simulated modules
/// (one link per serial line, the modules of a line on one multi-drop bus).
fn opener(
    buses: BTreeMap<u8, MultiDrop>,
    plans: BTreeMap<u8, FaultPlan>,
    modules: &[ModuleView],
) -> impl FnOnce(&RigConfig, &SharedClock, bool, &TransactionCounter) -> Result<Opened, OpenError> {
    let models: Vec<(u8, u8, SharedModel)> = modules
        .iter()
        .map(|m| (m.line, m.id, Arc::clone(&m.model)))
        .collect();
    move |config, clock, _simulate, count| {
        let mut lines: BTreeMap<u8, SharedLink> = BTreeMap::new();
        for (line, bus) in buses {
            let plan = plans.get(&line).cloned().unwrap_or_default();
            let link = FaultyLink::new(bus, render::port(line), Arc::clone(clock), plan);
            lines.insert(line, share(Box::new(Counted::new(link, Arc::clone(count)))));
        }
        let mut devices = Vec::new();
        let mut sim = SimRig::default();
        for (name, entry) in &config.devices {
            let DeviceConfig::C29u(c) = entry else {
                panic!("the fault search writes only TRP-C29U entries");
            };
            let line = render::line_of(&c.port.to_string())
                .unwrap_or_else(|| panic!("{name}: not a fault search port: {}", c.port));
            let link = lines
                .get(&line)
                .cloned()
                .unwrap_or_else(|| panic!("{name}: no line {line}"));
            let options = rigscript::runtime::devices::c29u_options(c);
            let open_error = |e| OpenError {
                device: name.clone(),
                source: rigscript::runtime::devices::DeviceError::C29u(e),
            };
            let driver = C29u::new(Arc::clone(&link), Arc::clone(clock), options.clone())
                .map_err(open_error)?;
            let probe = C29u::new(
                Arc::clone(&link),
                Arc::clone(clock),
                C29uOptions {
                    retries: 0,
                    ..options
                },
            )
            .map_err(open_error)?;
            devices.push(Device::C29u(Box::new(C29uDevice::new(
                name,
                c.clone(),
                driver,
                probe,
                link,
                None,
            ))));
            if let Some((_, _, model)) = models.iter().find(|(l, id, _)| *l == line && *id == c.id)
            {
                sim.insert(
                    name,
                    SimDevice::C29u {
                        model: Arc::clone(model),
                        presence: Presence::new(),
                        // The case's faults come from its FaultyLink, not from here.
                        faults: AnswerFaults::default(),
                    },
                );
            }
        }
        Ok(Opened { devices, sim })
    }
}
