//! `rigscript run SCRIPT`: runs a script on the rig's devices (or their simulators) in the
//! supervised scan loop until it ends, is stopped, or fails; logs what it does to stderr.
//!
//! Exit statuses: `runtime::exit` (shown by `run --help`).
//!
//! The run's one composition root: every service attaches here, the same way, to the run's
//! event stream, and those that ask the loop something through a `Requester` of the control
//! queue: the log and the records file (`RigBuilder::start`), systemd's notifications
//! (`service::notify`: READY=1 once every device is under control, WATCHDOG=1 while the loop
//! turns), the MQTT client (`service::mqtt`), the control socket and the web page; `--junit
//! FILE` writes the measurements as JUnit XML (`cli::run_outputs`).

use super::check::fit_to_run;
use super::output::say;
use super::run_outputs::RunOutputs;
use crate::config::{check_period, parse_memory_limit, RigConfig, WakeLatency, DEFAULT_UI};
use crate::guardian::lone::{Ending, LoneWatch};
use crate::guardian::pulse::{self, Phase};
use crate::guardian::{guard, Confirmation, Guarded, GuardianLog};
use crate::journal;
use crate::runtime::log::LogFormat;
use crate::runtime::observe::Events;
use crate::runtime::requests::{self, Requester, Requests};
use crate::runtime::{exit, signals};
use crate::script::builder::RigBuilder;
use crate::script::lint::warnings;
use crate::script::stack;
use crate::service::authority;
use crate::service::control_protocol::{Hello, PROTOCOL_VERSION};
use crate::service::control_socket::{self, Claim, ClaimError, Naming};
use crate::service::http::history::History;
use crate::service::http::{self, BindError};
use crate::service::mqtt;
use crate::service::reload::{Reloader, Watcher};
use crate::service::rig_dir;
use crate::sync::lock;
use crate::text_file::{read_text, TextKind};
use crate::time::duration::parse_duration;
use crate::time::zone::Zone;
use clap::Args;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::AtomicUsize;
use std::sync::{Arc, Mutex};
use std::time::Duration;

/// Options of `rigscript run`.
#[derive(Debug, Args)]
#[command(after_help = exit::TABLE)]
pub struct RunArgs {
    /// The script to run (.rhai).
    pub script: PathBuf,
    /// The rig: devices, period, error policy, records file.
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// Replace every device by its simulator (without --config: `panel`, a TRC1000, and
    /// `io`, a TRP-C29U at Modbus ID 1).
    #[arg(long)]
    pub sim: bool,
    /// Scan period, overriding rig.toml: a number with a unit ("20ms", "0.1s"), at most 10s.
    #[arg(long, value_name = "DURATION", value_parser = period)]
    pub period: Option<Duration>,
    /// End the run normally after this long: a number with a unit ("500ms", "10s", "5m",
    /// "24h", "1h30m"); a bare number is refused.
    #[arg(long = "for", value_name = "DURATION", value_parser = dur)]
    pub run_for: Option<Duration>,
    /// Append records and measurements to this JSON-lines file (overrides rig.toml); written
    /// off the loop, so records the file does not take in time are counted (exit status 5).
    #[arg(long)]
    pub records: Option<PathBuf>,
    /// At the end, print ticks, period jitter, tick work, overruns and transactions per tick.
    #[arg(long)]
    pub stats: bool,
    /// Log only warnings, errors, the script's own messages (print, log, warn) and the safe
    /// state the end wrote; leave out what the script does (outputs, events, timers) and the
    /// runner's notices (start-up, wake latency, stopping, stopped).
    #[arg(short, long)]
    pub quiet: bool,
    /// CPU wake-up latency to hold while running, overriding rig.toml: "auto" (0 µs while the
    /// loop ticks every 20 ms or faster), "off", or a duration ("0us", "50us"). Needs write access to
    /// /dev/cpu_dma_latency; idle CPUs poll instead of sleeping while it is held.
    #[arg(long, value_name = "auto|off|DURATION", value_parser = WakeLatency::parse)]
    pub wake_latency: Option<WakeLatency>,
    /// Operations each handler call may take before it is stopped as a runaway (default
    /// 1000000; `operations` under `[limits]` in rig.toml).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    pub budget: Option<u64>,
    /// How long each handler call may run, device exchanges included, before it is stopped as
    /// a runaway ("1s", "250ms"; default 1s; `handler_time` under `[limits]` in rig.toml).
    #[arg(long, value_name = "DURATION", value_parser = time_limit)]
    pub handler_time: Option<Duration>,
    /// The most heap memory the run may hold before the script is stopped ("256MiB",
    /// "1GiB", "512MB"; default 256MiB; `memory` under `[limits]` in rig.toml).
    #[arg(long, value_name = "SIZE", value_parser = memory_limit)]
    pub memory_limit: Option<u64>,
    /// The most timers (every, after, cron) armed at once; arming one more is a script error
    /// (default 10000; `timers` under `[limits]` in rig.toml).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(1..))]
    pub max_timers: Option<u32>,
    /// Log lines as text, or as one JSON object a line (time, level, source, message,
    /// device) for journald and Loki.
    #[arg(long, value_enum, value_name = "FORMAT", default_value_t = LogFormat::Text)]
    pub log_format: LogFormat,
    /// Also write the measurements as JUnit XML to FILE (Jenkins, GitLab): each `measure` a
    /// test case with its value and limits, plus one for the run itself.
    #[arg(long, value_name = "FILE")]
    pub junit: Option<PathBuf>,
    /// Run without the guardian process (docs/design/safety.md, "The guardian"): a runner that dies
    /// (kill -9, an abort, the OOM killer) then leaves the outputs as they were, but for each
    /// module's own host watchdog.
    #[arg(long)]
    pub no_guardian: bool,
    /// Simulate this device of rig.toml while the others are real (repeatable; the same as
    /// `sim = true` in its table): commissioning a rig whose panel or module is not there yet.
    #[arg(long, value_name = "NAME")]
    pub sim_device: Vec<String>,
    /// Serve the run's web page and HTTP API (state, events, metrics; under --sim, driving
    /// the simulated field) at ADDR (without ADDR: rig.toml's `ui`, else 127.0.0.1:7878; port
    /// 0: a free one, which the log says). An address other than loopback needs a token
    /// (`ui_token` in rig.toml or RIGSCRIPT_UI_TOKEN).
    #[arg(long, value_name = "ADDR", num_args = 0..=1)]
    pub ui: Option<Option<SocketAddr>>,
    /// Journal what the scan loop takes in (inputs read that changed, device losses and
    /// returns, overruns, reloads, forces and commands, the stop) and the outputs it writes to
    /// FILE, with the rig, the script's text and its hash, for `rigscript replay`. Written off
    /// the loop.
    #[arg(long, value_name = "FILE")]
    pub journal: Option<PathBuf>,
    /// The journal's bound ("64MiB" by default): a part that reaches half of it is moved to
    /// FILE.1 and a new one begins.
    #[arg(long, value_name = "SIZE", value_parser = memory_limit, requires = "journal")]
    pub journal_size: Option<u64>,
    /// Journal the rig's whole I/O image too: the inputs the script does not read are read
    /// as for someone watching (at most every 250 ms each, when a tick has the time on the
    /// line) and journaled apart, so a replay of an edited script that reads more has values
    /// for them.
    #[arg(long, requires = "journal")]
    pub journal_image: bool,
    /// The scenario tests a reload runs before it swaps the script in (default:
    /// tests/NAME.test.rhai beside the script, if there is one)
    #[arg(long, value_name = "PATH")]
    pub reload_tests: Option<PathBuf>,
    /// Reload the script whenever its file changes (once it has been unchanged for 300 ms),
    /// as `rigscript reload` does: checked and tested first, the outputs kept
    #[arg(long)]
    pub watch: bool,
    /// After a reload, go back to the previous script (and the state it had) if the new one
    /// raises an error or finds an invariant false within DURATION
    #[arg(long, value_name = "DURATION", value_parser = time_limit)]
    pub rollback: Option<Duration>,
}

fn dur(text: &str) -> Result<Duration, String> {
    parse_duration(text).map_err(|e| e.to_string())
}

fn time_limit(text: &str) -> Result<Duration, String> {
    match dur(text)? {
        d if d.is_zero() => Err("a time limit must be above zero".into()),
        d => Ok(d),
    }
}

fn memory_limit(text: &str) -> Result<u64, String> {
    parse_memory_limit(text).map_err(|e| e.to_string())
}

fn period(text: &str) -> Result<Duration, String> {
    check_period(dur(text)?).map_err(|why| format!("\"{text}\" {why}"))
}

/// Whether the run's own end confirmed the safe state of every device (a panic's end does not
/// confirm anything): the guardian then has nothing to do.
fn ended_safe(rig: &crate::script::rig::Rig, status: i32) -> bool {
    status != exit::INTERNAL && rig.runner.trouble.unreached_at_end.is_empty()
}

/// Runs `rigscript run`; returns the exit status.
pub fn run(args: RunArgs) -> i32 {
    let mut config = match (&args.config, args.sim) {
        (Some(path), _) => match RigConfig::load(path) {
            Ok(c) => c,
            Err(e) => {
                say(&format!("rigscript run: {e}"));
                return exit::USAGE;
            }
        },
        (None, true) => RigConfig::simulated_default(),
        (None, false) => {
            say(
                "rigscript run: give --config rig.toml (the devices to drive) or --sim \
                 (simulated devices: panel, a TRC1000, and io, a TRP-C29U)",
            );
            return exit::USAGE;
        }
    };
    if let Some(w) = args.wake_latency {
        config.wake_latency = w;
    }
    match args.ui {
        Some(Some(ui)) => config.ui = Some(ui),
        Some(None) if config.ui.is_none() => config.ui = DEFAULT_UI.parse().ok(),
        _ => {}
    }
    for name in &args.sim_device {
        if !config.devices.contains_key(name) {
            let known: Vec<&str> = config.devices.keys().map(String::as_str).collect();
            say(&format!(
                "rigscript run: --sim-device {name}: the rig has no device called {name} \
                 (devices: {})",
                known.join(", ")
            ));
            return exit::USAGE;
        }
        config.simulated.insert(name.clone());
    }
    let limits = &mut config.limits;
    limits.operations = args.budget.unwrap_or(limits.operations);
    limits.handler_time = args.handler_time.unwrap_or(limits.handler_time);
    limits.memory = args.memory_limit.unwrap_or(limits.memory);
    limits.timers = args.max_timers.map_or(limits.timers, |n| n as usize);
    let file = args.script.display().to_string();
    let mut outputs = match RunOutputs::new(&file, args.junit.clone()) {
        Ok(o) => o,
        Err(e) => {
            say(&format!("rigscript run: {e}"));
            return exit::USAGE;
        }
    };
    let source = match read_text(&args.script, TextKind::Script) {
        Ok(s) => s,
        Err(e) => {
            say(&format!("rigscript run: cannot read {file}: {e}"));
            return exit::USAGE;
        }
    };
    if !fit_to_run(
        "run",
        &file,
        &source,
        (&config, None),
        args.config.as_deref(),
    ) {
        return outputs.not_started(
            exit::USAGE,
            &format!("{file} does not pass rigscript check"),
        );
    }
    let stop_flag = Arc::new(AtomicUsize::new(0));
    // The flag holds the signal's number: the exit status reports which one it was.
    if let Err(e) = signals::watch(&stop_flag) {
        say(&format!("rigscript run: cannot watch for signals: {e}"));
        return exit::ERROR;
    }
    let control = ControlSetup {
        reloader: Reloader {
            script: args.script.clone(),
            config: config.clone(),
            tests: args.reload_tests.clone(),
        },
        watch: args.watch,
        rollback: args.rollback,
        queue: requests::queue(&stop_flag),
        rig: rig_dir::rig_name(config.name.as_deref(), args.config.as_deref(), &args.script),
        named: config.name.is_some(),
        config: args.config.as_ref().map(|p| p.display().to_string()),
    };
    let mut setup = RigBuilder::from_config(config)
        .log_format(args.log_format)
        .stop_flag(stop_flag);
    if args.sim {
        setup = setup.simulated();
    }
    if args.quiet {
        setup = setup.quiet();
    }
    if outputs.keeps_log() {
        setup = setup.keep_log();
    }
    if let Some(period) = args.period {
        setup = setup.period(period);
    }
    if let Some(end) = args.run_for {
        setup = setup.run_for(end);
    }
    if let Some(records) = &args.records {
        setup = setup.records(records);
    }
    // Before any device is touched: a journal that cannot be written refuses the run.
    let journal = match &args.journal {
        None => None,
        Some(path) => {
            let size = args.journal_size.unwrap_or(journal::write::DEFAULT_SIZE);
            let prepared = journal::Header::first(
                &file,
                &source,
                args.config.as_deref(),
                setup.config(),
                setup.scan_period(),
                args.run_for,
            )
            .map_err(|e| format!("journal: cannot read the rig.toml to keep: {e}"))
            .map(|mut header| {
                header.rollback_ms = args.rollback.map(crate::runtime::snapshot::millis);
                header
            })
            .and_then(|header| {
                let mut settings = journal::write::Settings::new(path, size);
                settings.image = args.journal_image;
                journal::write::Prepared::new(settings, header)
                    .map_err(|e| e.to_string())
            });
            match prepared {
                Ok(p) => Some(p),
                Err(e) => {
                    say(&format!("rigscript run: {e}"));
                    return exit::USAGE;
                }
            }
        }
    };
    let log = GuardianLog {
        format: args.log_format,
        zone: Zone::Local,
        stall: setup.config().stall_limit(setup.scan_period()),
    };
    let real_devices = setup.config().has_real_devices();
    let guardian = if args.no_guardian || args.sim || !real_devices {
        None
    } else {
        match guard(setup.config(), log) {
            Ok(Guarded::Runner(confirmation)) => Some(confirmation),
            Ok(Guarded::Guardian(status)) => return status,
            Err(e) => {
                say(&format!(
                    "rigscript run: {e}; nothing was started (--no-guardian runs without it)"
                ));
                return exit::ERROR;
            }
        }
    };
    // After the guardian's fork (which needs this process to have one thread): without a
    // guardian, a thread of this process watches the loop instead.
    let lone = match &guardian {
        Some(_) => None,
        None => match LoneWatch::start(log, Ending::Run { real_devices }) {
            Ok(w) => Some(w),
            Err(e) => {
                say(&format!("rigscript run: {e}"));
                return exit::ERROR;
            }
        },
    };
    // The run on a stack that holds whatever the script can build within its memory limit.
    let memory = setup.config().limits.memory;
    let stats = args.stats;
    stack::on_script_stack(memory, move || {
        let pulse = guardian
            .as_ref()
            .map(Confirmation::pulse)
            .or_else(|| lone.as_ref().map(LoneWatch::pulse));
        let _beating = pulse.map(pulse::attach);
        run_started(
            &source,
            &file,
            setup,
            &mut outputs,
            guardian,
            stats,
            Attached { control, journal },
        )
    })
}

/// The services prepared before any device is touched that attach to the run.
struct Attached {
    control: ControlSetup,
    journal: Option<journal::write::Prepared>,
}

/// The journal's file as the log names it.
fn setup_journal_name(journal: &Option<journal::write::Prepared>) -> String {
    journal
        .as_ref()
        .map(|j| j.path().display().to_string())
        .unwrap_or_default()
}

/// What the run's control socket needs (`service::control_socket`).
struct ControlSetup {
    /// How a reload through the socket is made ready.
    reloader: Reloader,
    /// `--watch`: reload when the script file changes.
    watch: bool,
    /// `--rollback`: how long a reload may still be undone.
    rollback: Option<Duration>,
    queue: (Requester, Requests),
    rig: String,
    /// Whether rig.toml gave the name (else it came from a file's stem).
    named: bool,
    config: Option<String>,
}

impl ControlSetup {
    /// Claims the rig's socket (before any device is touched: a second run of a rig must not
    /// take its devices).
    fn claim(&self, file: &str) -> Result<Claim, ClaimError> {
        let dir = rig_dir::rig_dir().map_err(|source| ClaimError::Io {
            path: PathBuf::from("the rig directory"),
            source,
        })?;
        let hello = Hello {
            protocol: PROTOCOL_VERSION,
            rig: self.rig.clone(),
            pid: std::process::id(),
            script: file.to_string(),
            config: self.config.clone(),
            started: chrono::Local::now().to_rfc3339_opts(chrono::SecondsFormat::Millis, false),
        };
        let naming = if self.named {
            Naming::Configured
        } else {
            Naming::Derived
        };
        control_socket::claim(&dir, hello, naming)
    }
}

/// The page's link for the log: with the run's key in its fragment (which a browser never
/// sends, so no server log or proxy sees it); under systemd, whose journal others may read,
/// the key stays in its file (`key_file`), which the link names instead.
fn page_link(
    addr: SocketAddr,
    key: Option<&authority::RunKey>,
    key_file: &Option<PathBuf>,
) -> String {
    let systemd = std::env::var_os("INVOCATION_ID").is_some();
    match (key, key_file) {
        (Some(_), Some(file)) if systemd => format!(
            "http://{addr}/ (changes need the run's key: http://{addr}/#key=KEY, KEY from {})",
            file.display()
        ),
        (Some(k), _) => format!("http://{addr}/#key={}", k.expose()),
        (None, _) => format!("http://{addr}/"),
    }
}

/// `setup` with `service`, if there is one, started by `start` on the run's events
/// (`RigBuilder::attach`), and where what that returned is found once the rig has started.
fn attach<S: Send + 'static, T: Send + 'static>(
    setup: RigBuilder,
    service: Option<S>,
    start: impl FnOnce(S, &Events) -> T + Send + 'static,
) -> (RigBuilder, Option<Started<T>>) {
    let Some(service) = service else {
        return (setup, None);
    };
    let slot = Started::default();
    let filled = Arc::clone(&slot);
    let setup = setup.attach(move |events| *lock(&filled) = Some(start(service, events)));
    (setup, Some(slot))
}

/// What a service attached by `attach` returned when it started.
type Started<T> = Arc<Mutex<Option<T>>>;

/// What the service attached returned, if it was attached and started.
fn taken<T>(slot: Option<Started<T>>) -> Option<T> {
    slot.and_then(|s| lock(&s).take())
}

/// A run refused before any device was touched, for `why`: says so, and tells the guardian
/// there is nothing for it to make safe; the exit status (`status`).
fn refused(why: &str, status: i32, guardian: Option<Confirmation>, outputs: &RunOutputs) -> i32 {
    say(&format!("rigscript run: {why}"));
    if let Some(g) = guardian {
        g.confirm();
    }
    outputs.not_started(status, why)
}

/// The run itself, from taking control of the devices to the last log line.
fn run_started(
    source: &str,
    file: &str,
    setup: RigBuilder,
    outputs: &mut RunOutputs,
    guardian: Option<Confirmation>,
    stats: bool,
    attached: Attached,
) -> i32 {
    let Attached { control, journal } = attached;
    let claim = match control.claim(file) {
        Ok(c) if c.hello().rig != control.rig => {
            say(&format!(
                "rigscript run: rig {} is running already: this run is rig {} (`name = \"...\"` \
                 in rig.toml names it)",
                control.rig,
                c.hello().rig
            ));
            Some(c)
        }
        Ok(c) => Some(c),
        // A rig directory that cannot be written costs the view from outside, not the run.
        Err(e @ ClaimError::Io { .. }) => {
            say(&format!(
                "rigscript run: warning: {e}; `rigscript status` will not see this run"
            ));
            None
        }
        Err(e) => return refused(&e.to_string(), exit::UNAVAILABLE, guardian, outputs),
    };
    // Before any device is touched, like the socket: an address in use costs nothing.
    let key = match authority::RunKey::generate() {
        Ok(k) => Some(k),
        Err(e) => {
            say(&format!(
                "rigscript run: warning: no key for this run ({e}): the web page changes \
                 nothing without the ui_token"
            ));
            None
        }
    };
    let mut claim = claim;
    if let Some(c) = claim.as_mut() {
        c.reloads(control.reloader.clone());
    }
    let key_file = match (claim.as_mut(), key.as_ref()) {
        (Some(c), Some(k)) => c
            .keep_key(k)
            .map_err(|e| {
                say(&format!(
                    "rigscript run: warning: cannot keep the run's key beside {}: {e}",
                    c.path().display()
                ));
            })
            .ok(),
        _ => None,
    };
    let tokens = match http::auth::Tokens::from(
        setup.config().ui_token.as_ref(),
        setup.config().ui_read_token.as_ref(),
        key.clone(),
    ) {
        Ok(t) => t,
        Err(e) => return refused(&e.to_string(), exit::USAGE, guardian, outputs),
    };
    let web = match setup
        .config()
        .ui
        .map(|addr| http::bind(addr, tokens))
        .transpose()
    {
        Ok(w) => w,
        Err(e) => {
            let status = match e {
                BindError::NotLoopback(_) => exit::USAGE,
                BindError::Io { .. } => exit::UNAVAILABLE,
            };
            return refused(&e.to_string(), status, guardian, outputs);
        }
    };
    // Before any device is touched too: a password or an outbox that cannot be had.
    let run_name = claim
        .as_ref()
        .map_or(control.rig.clone(), |c| c.hello().rig.clone());
    let mqtt = match setup.mqtt().map(|m| {
        mqtt::Settings::resolve(m, &run_name, setup.records_file()).and_then(mqtt::Prepared::new)
    }) {
        None => None,
        Some(Ok(p)) => Some(p),
        Some(Err(e)) => return refused(&e.to_string(), exit::USAGE, guardian, outputs),
    };
    let (requester, requests) = control.queue;
    let watcher = control
        .watch
        .then(|| (control.reloader.clone(), requester.clone()));
    // Every service attaches to the run's events before its top level runs: the MQTT client
    // and systemd's notifier must see the first start, and all attach the same way.
    let asker = requester.clone();
    let (setup, client) = attach(setup, mqtt, move |p, events| p.start(events, asker));
    let devices: Vec<&str> = setup.config().devices.keys().map(String::as_str).collect();
    let status = format!("running {file} on {}", devices.join(", "));
    let notifier = outputs.take_notifier();
    let (setup, notifying) = attach(setup, notifier, move |n, events| n.attach(events, status));
    let ui = web.as_ref().map(|w| w.addr());
    let asker = requester.clone();
    // The page's history follows the run from its first line, so its log has the take-over
    // lines and each module's identity.
    let early = Arc::new(Mutex::new(None));
    let setup = match web.is_some() {
        true => {
            let early = Arc::clone(&early);
            setup.watch_from_start(move |events| *lock(&early) = Some(History::follow(events)))
        }
        false => setup,
    };
    let (setup, page) = attach(setup, web, move |w, events| {
        let history = lock(&early).take();
        w.serve(asker, events, history)
    });
    let (setup, server) = attach(setup, claim, move |c, events| {
        c.serve(requester, events.clone())
    });
    let journal_path = setup_journal_name(&journal);
    let (setup, journaling) = attach(setup, journal, |j, events| j.start(events));
    // `check`'s warnings go to the run's log, in its format, once it has started.
    let warned = warnings(source, setup.scan_period());
    let started = setup.start(source, file);
    let notifying = match taken(notifying) {
        Some(Ok(n)) => Some(n),
        Some(Err(e)) => {
            say(&format!("rigscript run: {e}"));
            None
        }
        None => None,
    };
    let mut rig = match started {
        Ok(r) => r,
        Err(e) => {
            say(&format!("rigscript run: {e}"));
            // A run that never started drove nothing but the safe state taking control writes.
            if let (Some(g), false) = (guardian, e.status() == exit::INTERNAL) {
                g.confirm();
            }
            if let Some(n) = notifying {
                n.finish(e.status());
            }
            return outputs.not_started(e.status(), &e.to_string());
        }
    };
    for w in &warned {
        rig.runner
            .runtime()
            .borrow_mut()
            .log_mut()
            .warn(&w.in_file(file));
    }
    let journaling = match taken(journaling) {
        Some(Ok(j)) => Some(j),
        Some(Err(e)) => {
            rig.runner
                .runtime()
                .borrow_mut()
                .log_mut()
                .warn(&format!("{e}; the run goes on without its journal"));
            None
        }
        None => None,
    };
    let client = match taken(client) {
        Some(Err(e)) => {
            say(&format!(
                "rigscript run: warning: {e}; the run goes on without the broker"
            ));
            None
        }
        Some(Ok(c)) => Some(c),
        None => None,
    };
    let field = rig.sim.clone();
    rig.runner.serve(requests, file, field);
    rig.runner.set_rollback(control.rollback);
    let _watching = watcher.and_then(|(reloader, ask)| {
        Watcher::start(reloader, ask, source.to_string())
            .map_err(|e| say(&format!("rigscript run: warning: cannot watch {file}: {e}")))
            .ok()
    });
    if let Some(addr) = ui {
        say(&format!(
            "rigscript run: ui: {}",
            page_link(addr, key.as_ref(), &key_file)
        ));
    }
    let status = rig.runner.run();
    // What follows (the last events, the broker's goodbye, the log) is not the loop's.
    pulse::enter(Phase::Ended);
    // The last events to the subscribers (`rigscript stop` waits for the end's), then the
    // socket and the page go.
    drop(taken(server));
    drop(taken(page));
    if let Some(c) = client {
        c.finish();
    }
    if let (Some(g), true) = (guardian, ended_safe(&rig, status)) {
        g.confirm();
    }
    if let Some(warning) = journaling.and_then(|j| j.finish().warning(&journal_path)) {
        rig.runner.runtime().borrow_mut().log_mut().warn(&warning);
    }
    if let Some(report) = notifying.and_then(|n| n.finish(status)) {
        rig.runner.runtime().borrow_mut().log_mut().warn(&report);
    }
    let status = outputs.finished(&rig, status);
    // The last lines out (at most a second's wait for a stderr nobody reads).
    rig.runner.runtime().borrow_mut().close_log();
    if stats {
        // The whole picture at the end, as `status` shows one during the run. After the end:
        // a reader that went away costs the figures, never the status.
        let _ = std::io::Write::write_fmt(
            &mut std::io::stdout(),
            format_args!("{}\n", rig.runner.snapshot().stats_text()),
        );
    }
    status
}
