//! One case of the fault search, as plain data that proptest makes and shrinks: a rig (the
//! rig.toml entries), a script (statements of the script API) and a fault schedule (a list of
//! `(virtual ms, fault)` events, which shrinks by dropping events and moving them earlier).
//!
//! Values come from disjoint pools, so the oracle can tell from a DO byte alone whose it is:
//! a configured safe value, one the script commands, a power-on value, or something else.

use proptest::prelude::*;
use proptest::sample::select;

/// Safe values a rig.toml may set.
pub const SAFE_POOL: [u8; 4] = [0x00, 0x05, 0x0F, 0xFF];
/// Values the script writes to the outputs.
pub const COMMAND_POOL: [u8; 4] = [0x30, 0x41, 0x52, 0x63];
/// Channels the script switches one by one (so commanded values are the pool with these bits
/// free, which stays clear of the pools below).
pub const BIT_CHANNELS: [u8; 2] = [3, 4];
/// Power-on values a rig.toml may set.
pub const POWER_ON_POOL: [u8; 2] = [0x9C, 0xA6];
/// Safe values the script stores with `io.safe_value = ..`.
pub const SCRIPT_SAFE_POOL: [u8; 2] = [0xC3, 0xD9];
/// Power-on values the script stores with `io.power_on_value = ..`.
pub const SCRIPT_POWER_ON_POOL: [u8; 2] = [0xE5, 0xB7];
/// DI bytes the field puts on the inputs (0 at power on).
pub const INPUT_POOL: [u8; 4] = [0x00, 0x01, 0x02, 0x03];
/// Arguments of `io.watchdog(..)`: legal, out of range, and one that overflows.
pub const WATCHDOG_ARGS: [&str; 5] = ["1", "0.5", "2.5", "30", "1e17"];
/// A timeout no module should be waited on ("1000000h"), in ms.
pub const HUGE_TIMEOUT_MS: u64 = 1_000_000 * 3_600_000;

/// Which protocol a module's DIP switch selects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Proto {
    /// Modbus RTU.
    Modbus,
    /// The ASCII protocol.
    Ascii,
}

/// One `[devices.ioN]` entry of rig.toml, and the module it names as found on the bench.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Module {
    /// The DIP switch.
    pub protocol: Proto,
    /// Which serial line (0 or 1): entries on one line share it (multi-drop).
    pub line: u8,
    /// The module's ID; two entries with the same line and ID name the same module.
    pub id: u8,
    /// `timeout`, in ms.
    pub timeout_ms: u64,
    /// `retries`.
    pub retries: u8,
    /// `watchdog`, in 0.1 s (None: no watchdog).
    pub watchdog_tenths: Option<u8>,
    /// `safe_value`.
    pub safe: u8,
    /// `power_on_value`.
    pub power_on: Option<u8>,
    /// The module comes with factory EEPROM (else as the rig.toml would leave it).
    pub fresh: bool,
}

/// What a handler error does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Policy {
    /// End the run.
    Stop,
    /// Start the script again.
    Restart,
    /// Go on.
    Skip,
}

/// The rig.toml and the run's options.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Rig {
    /// `period`, in ms.
    pub period_ms: u64,
    /// `on_error`.
    pub policy: Policy,
    /// `grace`, in ms.
    pub grace_ms: u64,
    /// `--for`, in ms.
    pub run_for_ms: u64,
    /// Operations per handler call (`operations` under [limits]).
    pub budget: u64,
    /// The entries `io0`, `io1`.
    pub modules: Vec<Module>,
}

/// A statement of the script; `dev` picks an entry (modulo their number).
#[derive(Debug, Clone, PartialEq)]
pub enum Stmt {
    /// `ioN.outputs = value;`
    Set { dev: u8, value: u8 },
    /// `ioN.set_output(ch, on);`
    SetBit { dev: u8, ch: u8, on: bool },
    /// `record("diN", ioN.inputs);` (the oracle checks the value against the field)
    RecordInputs { dev: u8 },
    /// `record("ioN.counters", ioN.counters());` (the oracle checks them against the field)
    RecordCounters { dev: u8 },
    /// `ioN.safe_value = value;`
    SafeValue { dev: u8, value: u8 },
    /// `ioN.power_on_value = value;`
    PowerOnValue { dev: u8, value: u8 },
    /// `ioN.watchdog(seconds);`
    Watchdog { dev: u8, seconds: &'static str },
    /// `ioN.watchdog_off();`
    WatchdogOff { dev: u8 },
    /// `ioN.reset();`
    Reset { dev: u8 },
    /// Throws on the `on_call`-th time it runs.
    Throw { on_call: u8 },
    /// A loop of `iterations` steps (over the budget when large).
    Spin { iterations: u32 },
    /// `timers` timers that each hold four 32 KB strings (memory that only grows).
    Grow { timers: u16 },
    /// A string doubled until it is too large.
    BigString,
    /// `stop(code);`
    Stop { code: u8 },
    /// `every("ms", || { body });`
    Every { ms: u64, body: Vec<Stmt> },
    /// `after("ms", || { body });`
    After { ms: u64, body: Vec<Stmt> },
    /// `ioN.on_rise(ch, || { body });`
    OnRise { dev: u8, ch: u8, body: Vec<Stmt> },
    /// `ioN.on_fall(ch, || { body });`
    OnFall { dev: u8, ch: u8, body: Vec<Stmt> },
    /// `on_stop(|| { body });`
    OnStop { body: Vec<Stmt> },
}

/// Something that goes wrong; `line` and `dev` are taken modulo the lines and entries there are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InjectedFault {
    /// The field sets the DI byte of `dev`'s module.
    Input { dev: u8, value: u8 },
    /// SIGTERM.
    Sigterm,
    /// kill -9: the runner is gone, nothing it sends arrives any more.
    Kill,
    /// The next answers on the line are lost.
    Drop { line: u8, answers: u8 },
    /// The next answer on the line has a byte changed.
    Flip { line: u8, at: u8, xor: u8 },
    /// The next answer on the line comes `ms` late.
    Late { line: u8, ms: u64 },
    /// The next call on the line blocks for `ms`.
    LinkStall { line: u8, ms: u64 },
    /// The line's modules hear and say nothing for `ms` (a cut pair).
    Silence { line: u8, ms: u64 },
    /// The line's adapter is unplugged for `ms`; its modules lose power and boot again.
    Unplug { line: u8, ms: u64 },
    /// `dev`'s module is power cycled behind the runner's back.
    ModuleReset { dev: u8 },
    /// Another module answers in `dev`'s module's place on its line (same ID), with these
    /// stored safe and power-on values and no watchdog, powered on as it is swapped in.
    Swap { dev: u8, safe: u8, power_on: u8 },
    /// `dev`'s module's output stage is faulty for `ms`: output writes acknowledged and not
    /// applied (`refuse: None`), or refused with that Modbus exception code.
    OutputStage {
        dev: u8,
        refuse: Option<u8>,
        ms: u64,
    },
    /// The runner's process stalls for `ms` (the module's time goes on).
    Freeze { ms: u64 },
    /// The next call on the line panics.
    Panic { line: u8 },
}

/// A whole case.
#[derive(Debug, Clone, PartialEq)]
pub struct Case {
    /// The rig.
    pub rig: Rig,
    /// The script's top level.
    pub script: Vec<Stmt>,
    /// The faults, each at a virtual time in ms from the start.
    pub faults: Vec<(u64, InjectedFault)>,
}

impl Case {
    /// The serial lines the rig uses.
    pub fn lines(&self) -> Vec<u8> {
        let mut lines: Vec<u8> = self.rig.modules.iter().map(|m| m.line).collect();
        lines.sort_unstable();
        lines.dedup();
        lines
    }

    /// The entry a statement's or fault's `dev` picks.
    pub fn entry(&self, dev: u8) -> usize {
        usize::from(dev) % self.rig.modules.len().max(1)
    }

    /// The line a fault's `line` picks.
    pub fn line(&self, line: u8) -> u8 {
        let lines = self.lines();
        lines
            .get(usize::from(line) % lines.len().max(1))
            .copied()
            .unwrap_or(0)
    }

    /// Every statement of the script, handlers' bodies included.
    pub fn statements(&self) -> Vec<&Stmt> {
        fn walk<'a>(body: &'a [Stmt], out: &mut Vec<&'a Stmt>) {
            for s in body {
                out.push(s);
                match s {
                    Stmt::Every { body, .. }
                    | Stmt::After { body, .. }
                    | Stmt::OnRise { body, .. }
                    | Stmt::OnFall { body, .. }
                    | Stmt::OnStop { body } => walk(body, out),
                    _ => {}
                }
            }
        }
        let mut out = Vec::new();
        walk(&self.script, &mut out);
        out
    }
}

fn module() -> impl Strategy<Value = Module> {
    let timeout = prop_oneof![
        16 => select(vec![100u64, 50, 200, 500]),
        1 => Just(HUGE_TIMEOUT_MS),
    ];
    // Mostly watchdogs long enough for the exchanges a rig may make (a runner refuses shorter
    // ones), some shorter to see them refused or fed on time.
    let watchdog = prop_oneof![
        3 => Just(None),
        4 => select(vec![50u8, 100, 255]).prop_map(Some),
        1 => select(vec![10u8, 3, 20]).prop_map(Some),
    ];
    (
        prop_oneof![Just(Proto::Modbus), Just(Proto::Ascii)],
        0..2u8,
        1..4u8,
        timeout,
        0..3u8,
        watchdog,
        select(SAFE_POOL.to_vec()),
        proptest::option::of(select(POWER_ON_POOL.to_vec())),
        any::<bool>(),
    )
        .prop_map(
            |(protocol, line, id, timeout_ms, retries, watchdog_tenths, safe, power_on, fresh)| {
                Module {
                    protocol,
                    line,
                    id,
                    timeout_ms,
                    retries,
                    watchdog_tenths,
                    safe,
                    power_on,
                    fresh,
                }
            },
        )
}

fn rig() -> impl Strategy<Value = Rig> {
    (
        select(vec![100u64, 20, 50, 500, 2000]),
        prop_oneof![
            Just(Policy::Stop),
            Just(Policy::Restart),
            Just(Policy::Skip)
        ],
        select(vec![1000u64, 500, 3000]),
        2_000..30_000u64,
        select(vec![200_000u64, 20_000]),
        prop_oneof![
            2 => prop::collection::vec(module(), 1..=1),
            1 => prop::collection::vec(module(), 2..=2),
        ],
    )
        .prop_map(
            |(period_ms, policy, grace_ms, run_for_ms, budget, mut modules)| {
                // Modules on one line speak one protocol (the line is one bus).
                if let [first, second] = modules.as_mut_slice() {
                    if first.line == second.line {
                        second.protocol = first.protocol;
                    }
                }
                Rig {
                    period_ms,
                    policy,
                    grace_ms,
                    run_for_ms,
                    budget,
                    modules,
                }
            },
        )
}

fn simple_statement() -> impl Strategy<Value = Stmt> {
    let dev = 0..2u8;
    prop_oneof![
        12 => (dev.clone(), select(COMMAND_POOL.to_vec())).prop_map(|(dev, value)| Stmt::Set { dev, value }),
        3 => (dev.clone(), select(BIT_CHANNELS.to_vec()), any::<bool>())
            .prop_map(|(dev, ch, on)| Stmt::SetBit { dev, ch, on }),
        4 => dev.clone().prop_map(|dev| Stmt::RecordInputs { dev }),
        2 => dev.clone().prop_map(|dev| Stmt::RecordCounters { dev }),
        1 => (dev.clone(), select(SCRIPT_SAFE_POOL.to_vec()))
            .prop_map(|(dev, value)| Stmt::SafeValue { dev, value }),
        1 => (dev.clone(), select(SCRIPT_POWER_ON_POOL.to_vec()))
            .prop_map(|(dev, value)| Stmt::PowerOnValue { dev, value }),
        1 => (dev.clone(), select(WATCHDOG_ARGS.to_vec()))
            .prop_map(|(dev, seconds)| Stmt::Watchdog { dev, seconds }),
        1 => dev.clone().prop_map(|dev| Stmt::WatchdogOff { dev }),
        1 => dev.prop_map(|dev| Stmt::Reset { dev }),
        1 => (1..6u8).prop_map(|on_call| Stmt::Throw { on_call }),
        1 => select(vec![10u32, 1_000, 1_000_000]).prop_map(|iterations| Stmt::Spin { iterations }),
        2 => select(vec![200u16, 20]).prop_map(|timers| Stmt::Grow { timers }),
        1 => Just(Stmt::BigString),
        1 => (0..4u8).prop_map(|code| Stmt::Stop { code }),
    ]
}

fn statement() -> impl Strategy<Value = Stmt> {
    simple_statement().prop_recursive(2, 12, 3, |inner| {
        let body = prop::collection::vec(inner, 0..=3);
        prop_oneof![
            4 => (select(vec![100u64, 50, 300, 1000]), body.clone())
                .prop_map(|(ms, body)| Stmt::Every { ms, body }),
            1 => (select(vec![500u64, 2000]), body.clone())
                .prop_map(|(ms, body)| Stmt::After { ms, body }),
            2 => (0..2u8, 0..2u8, body.clone())
                .prop_map(|(dev, ch, body)| Stmt::OnRise { dev, ch, body }),
            1 => (0..2u8, 0..2u8, body.clone())
                .prop_map(|(dev, ch, body)| Stmt::OnFall { dev, ch, body }),
            1 => body.prop_map(|body| Stmt::OnStop { body }),
        ]
    })
}

fn fault() -> impl Strategy<Value = InjectedFault> {
    let line = 0..2u8;
    let long = select(vec![1500u64, 400, 3000, 8000, 12_000]);
    prop_oneof![
        4 => (0..2u8, select(INPUT_POOL.to_vec())).prop_map(|(dev, value)| InjectedFault::Input { dev, value }),
        1 => Just(InjectedFault::Sigterm),
        1 => Just(InjectedFault::Kill),
        2 => (line.clone(), 1..4u8).prop_map(|(line, answers)| InjectedFault::Drop { line, answers }),
        2 => (line.clone(), any::<u8>(), any::<u8>())
            .prop_map(|(line, at, xor)| InjectedFault::Flip { line, at, xor }),
        2 => (line.clone(), select(vec![250u64, 60, 1000]))
            .prop_map(|(line, ms)| InjectedFault::Late { line, ms }),
        1 => (line.clone(), long.clone()).prop_map(|(line, ms)| InjectedFault::LinkStall { line, ms }),
        1 => (line.clone(), long.clone()).prop_map(|(line, ms)| InjectedFault::Silence { line, ms }),
        1 => (line.clone(), long.clone()).prop_map(|(line, ms)| InjectedFault::Unplug { line, ms }),
        1 => (0..2u8).prop_map(|dev| InjectedFault::ModuleReset { dev }),
        1 => (0..2u8, select(SAFE_POOL.to_vec()), select(POWER_ON_POOL.to_vec()))
            .prop_map(|(dev, safe, power_on)| InjectedFault::Swap { dev, safe, power_on }),
        1 => (0..2u8, select(vec![None, Some(0x04), Some(0xFF)]), long.clone())
            .prop_map(|(dev, refuse, ms)| InjectedFault::OutputStage { dev, refuse, ms }),
        1 => long.prop_map(|ms| InjectedFault::Freeze { ms }),
        1 => line.prop_map(|line| InjectedFault::Panic { line }),
    ]
}

/// Cases: a rig, a script of one to four top-level statements, up to six faults.
pub fn cases() -> impl Strategy<Value = Case> {
    (
        rig(),
        prop::collection::vec(statement(), 1..=4),
        prop::collection::vec((0..30_000u64, fault()), 0..=6),
    )
        .prop_map(|(rig, script, faults)| Case {
            rig,
            script,
            faults,
        })
}
