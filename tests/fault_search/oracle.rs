//! The fault search's judgement of one run, from the simulated modules' own output history
//! and state, the field inputs it set, and the run's exit status and log:
//! - outputs only ever held a configured safe value, a value the script commands, or the
//!   power-on value after a power cycle the runner did not cause (`unsafe-write`,
//!   `unsafe-safe-value`, `runner-reset`);
//! - after any end the outputs are at the safe value, the stored safe value and watchdog as
//!   configured, and once the modules have been on their own for longer than any watchdog the
//!   outputs are safe (`end-not-safe`; `panic-not-safe` after a panic; `end-skipped-reachable`
//!   when the runner counted an answering module lost; `end-not-safe-shared-module` when two
//!   entries name one module; `safe-value-changed`, `watchdog-weakened`,
//!   `not-safe-after-end`);
//! - a module's watchdog fires only when a fault explains it, and after a stall that let it
//!   fire the script's outputs come back at once (`spurious-watchdog`, `late-restore`);
//! - the run ends in time, within bounded memory and work (`hang`, `memory`,
//!   `unbounded-work`), its exit status
//!   matches why it ended (`exit-status`), and what the script reads of the inputs is what
//!   the field put on them (`wrong-input`; not where ASCII cannot tell: an answer flipped into
//!   another well-formed one, or one later than twice the timeout); a clean status after a
//!   failure is `exit-hides-failure` (the statuses are `runtime::exit`'s);
//! - a script error says where in the script it happened (`error-without-location`);
//! - nothing is written to a module's EEPROM that it holds already, unless an answer on its
//!   line was lost (`eeprom-rewrite`);
//! - a module whose output stage is faulty (writes ignored or refused) cannot be made safe by
//!   the runner: at the end it is excused from `end-not-safe` only if the end named it as not
//!   reached (else `end-unconfirmed-not-said`), its watchdog must be left on
//!   (`watchdog-weakened`), and a write refused during the run makes the exit status say so;
//! - a module swapped for another (its own stored values, no watchdog) is found at the next
//!   check and taken control of: only one swapped in less than a check (and its exchanges)
//!   before the runner stopped is excused from `safe-value-changed`, `watchdog-weakened` and
//!   `not-safe-after-end`.

use super::case::{Case, InjectedFault, Proto, Stmt};
use super::harness::{End, Run, CLOCK_READS_CAP, MEMORY_MARKER, WORK_MARKER};
use super::render;
use rigscript::runtime::exit;
use rigscript::sim::c29u::{OutputCause, OutputChange};
use rigscript::sim::c29u_line::lock;
use rigscript::sim::faults::{Connection, LinkFault};
use std::collections::BTreeSet;

/// The signal the search sends (SIGTERM).
pub const SIGTERM: i32 = 15;

/// How the end's safe state reports a device it did not reach (`safety::safe_state`): part of
/// the end, not what began it.
const END_NOT_REACHED: &str = ": the safe state did not reach it: ";
use std::fmt;
use std::time::Duration;

/// One broken promise.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Violation {
    /// A short stable name of the rule (see the module doc).
    pub kind: &'static str,
    /// What happened.
    pub detail: String,
}

impl fmt::Display for Violation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "[{}] {}", self.kind, self.detail)
    }
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn at(t: Duration) -> String {
    format!("{:.3}s", t.as_secs_f64())
}

fn bytes(set: &BTreeSet<u8>) -> String {
    let v: Vec<String> = set.iter().map(|b| format!("{b:#04x}")).collect();
    v.join(", ")
}

/// What the rules need to know about the case.
struct Facts<'a> {
    case: &'a Case,
    run: &'a Run,
    v: Vec<Violation>,
}

/// Everything `run` broke, in the order found.
pub fn check(case: &Case, run: &Run) -> Vec<Violation> {
    if let End::ConfigRefused(_) = run.end {
        return Vec::new();
    }
    let mut f = Facts {
        case,
        run,
        v: Vec::new(),
    };
    f.limits();
    for i in 0..run.modules.len() {
        f.outputs_held(i);
        f.spurious_watchdog(i);
        f.restore_after_stall(i);
    }
    f.end_state();
    f.exit_status();
    f.inputs();
    f.error_locations();
    f.v
}

impl Facts<'_> {
    fn push(&mut self, kind: &'static str, detail: String) {
        self.v.push(Violation { kind, detail });
    }

    /// When the runner stopped acting on the modules (killed, or ended).
    fn runner_gone(&self) -> Duration {
        self.run
            .killed_at
            .map_or(self.run.ended_at, |k| k.min(self.run.ended_at))
    }

    /// The run was cut short by the search itself (hang, memory).
    fn cut_short(&self) -> bool {
        self.run.hang || self.run.memory.is_some() || self.run.runaway
    }

    fn names(&self, i: usize) -> String {
        let e: Vec<String> = self.run.modules[i]
            .entries
            .iter()
            .map(|e| render::name(*e))
            .collect();
        e.join("/")
    }

    fn safes(&self, i: usize) -> BTreeSet<u8> {
        self.run.modules[i]
            .entries
            .iter()
            .map(|e| self.case.rig.modules[*e].safe)
            .collect()
    }

    fn addresses(&self, i: usize, dev: u8) -> bool {
        self.run.modules[i].entries.contains(&self.case.entry(dev))
    }

    /// The DO bytes the script can command on module `i`: its safe values and the values it
    /// writes, with the bits it switches one by one free.
    fn commanded(&self, i: usize) -> BTreeSet<u8> {
        let mut values = self.safes(i);
        let mut bits = 0u8;
        for s in self.case.statements() {
            match s {
                Stmt::Set { dev, value } if self.addresses(i, *dev) => {
                    values.insert(*value);
                }
                Stmt::SetBit { dev, ch, .. } if self.addresses(i, *dev) => bits |= 1 << ch,
                _ => {}
            }
        }
        let mut all = BTreeSet::new();
        for v in values {
            let base = v & !bits;
            // Every subset of `bits`.
            let mut sub = bits;
            loop {
                all.insert(base | sub);
                if sub == 0 {
                    break;
                }
                sub = (sub - 1) & bits;
            }
        }
        all
    }

    fn script_resets(&self, i: usize) -> bool {
        self.case
            .statements()
            .iter()
            .any(|s| matches!(s, Stmt::Reset { dev } if self.addresses(i, *dev)))
    }

    fn history(&self, i: usize) -> Vec<OutputChange> {
        lock(&self.run.modules[i].model)
            .output_history()
            .entries()
            .to_vec()
    }

    fn limits(&mut self) {
        if let Some(grown) = self.run.memory {
            self.push(
                "memory",
                format!(
                    "the heap grew by {} MiB during the run with no script error: the script's \
                     memory has no bound",
                    grown >> 20
                ),
            );
        }
        if self.run.runaway {
            self.push(
                "unbounded-work",
                format!(
                    "the runner read the clock {CLOCK_READS_CAP} times in one run with no \
                     script error: work that only grows (timers or handlers piling up?)"
                ),
            );
        }
        if self.run.hang && self.run.killed_at.is_none() {
            self.push(
                "hang",
                format!(
                    "the run had not ended at {} (ends asked for: --for {}, SIGTERM at {})",
                    at(self.run.bound),
                    at(ms(self.case.rig.run_for_ms)),
                    self.run.sigterm_at.map_or("-".into(), at)
                ),
            );
        }
        for (i, m) in self.run.modules.iter().enumerate() {
            // After a write whose answer was lost, writing again is the only way to be sure.
            // A module swapped for another makes what the runner read of it before stale: a
            // takeover under way when it happens writes from the old module's values.
            let answers_lost = self.case.faults.iter().any(|&(_, f)| match f {
                InjectedFault::Swap { dev, .. } => self.addresses(i, dev),
                InjectedFault::Drop { line, .. }
                | InjectedFault::Flip { line, .. }
                | InjectedFault::Late { line, .. }
                | InjectedFault::LinkStall { line, .. }
                | InjectedFault::Silence { line, .. }
                | InjectedFault::Unplug { line, .. }
                | InjectedFault::Panic { line } => self.case.line(line) == m.line,
                _ => false,
            });
            let rewrites = lock(&m.model).eeprom_rewrites();
            if rewrites > 0 && !answers_lost {
                let name = self.names(i);
                self.push(
                    "eeprom-rewrite",
                    format!(
                        "{name}: {rewrites} EEPROM write(s) stored a value the module already had"
                    ),
                );
            }
            let lost = lock(&m.model).output_history().lost();
            if lost > 0 {
                let name = self.names(i);
                self.push(
                    "history-overflow",
                    format!("{name}: {lost} output changes not kept; raise HISTORY_CAPACITY"),
                );
            }
        }
    }

    /// Every DO setting of module `i` against what it may be.
    fn outputs_held(&mut self, i: usize) {
        let name = self.names(i);
        let safes = self.safes(i);
        let commanded = self.commanded(i);
        let resets = self.script_resets(i);
        for c in self.history(i) {
            let what = format!(
                "{name} outputs {:#04x} -> {:#04x} at {}",
                c.before,
                c.after,
                at(c.at)
            );
            match c.cause {
                OutputCause::HostWrite if !commanded.contains(&c.after) => self.push(
                    "unsafe-write",
                    format!(
                        "{what}, written by the host: neither a safe value ({}) nor one the \
                         script commands ({})",
                        bytes(&safes),
                        bytes(&commanded)
                    ),
                ),
                OutputCause::WatchdogFired
                | OutputCause::PowerOn { in_safe_mode: true }
                | OutputCause::Reset { in_safe_mode: true }
                    if !safes.contains(&c.after) =>
                {
                    self.push(
                        "unsafe-safe-value",
                        format!(
                            "{what} ({:?}): the module's stored safe value is not the configured \
                             one ({})",
                            c.cause,
                            bytes(&safes)
                        ),
                    );
                }
                OutputCause::Reset {
                    in_safe_mode: false,
                } if !resets => self.push(
                    "runner-reset",
                    format!("{what}: a reset by the host that the script did not ask for"),
                ),
                _ => {}
            }
        }
    }

    /// Whether module `i`'s output stage was faulty at some time between `from` and `to`.
    fn stage_faulty(&self, i: usize, from: Duration, to: Duration) -> bool {
        self.case.faults.iter().any(|&(start, f)| match f {
            InjectedFault::OutputStage { dev, ms: d, .. } => {
                self.addresses(i, dev) && ms(start) <= to && ms(start) + ms(d) >= from
            }
            _ => false,
        })
    }

    /// Whether module `i` was swapped for another too shortly before `t` for the runner's
    /// periodic check to have found it (5 s, and the check's exchanges), or after it (no one
    /// is left to take control of the new one).
    /// A frozen runner checks nothing, nor does one stalled in a call on any line (its one
    /// thread waits in that call), nor one whose line to the module is down, so that time
    /// between the swap and `t` does not count towards the check's window.
    fn swapped_unseen(&self, i: usize, t: Duration) -> bool {
        let window = ms(5000) + ms(2 * self.case.rig.period_ms) + self.slowest_exchange() * 8;
        self.case.faults.iter().any(|&(start, f)| match f {
            InjectedFault::Swap { dev, .. } => {
                let from = ms(start);
                self.addresses(i, dev) && from + window + self.blind_between(i, from, t) >= t
            }
            _ => false,
        })
    }

    /// How long, between `from` and `to`, the runner was frozen, stalled in a link call (on
    /// any line: the scan loop is one thread) or module `i`'s line down (overlaps counted once
    /// each: an over-estimate only widens the excuse by that much).
    fn blind_between(&self, i: usize, from: Duration, to: Duration) -> Duration {
        let line = self.run.modules[i].line;
        self.case
            .faults
            .iter()
            .filter_map(|&(start, f)| {
                match f {
                    InjectedFault::Freeze { ms: d } | InjectedFault::LinkStall { ms: d, .. } => {
                        Some(d)
                    }
                    InjectedFault::Silence { line: l, ms: d }
                    | InjectedFault::Unplug { line: l, ms: d }
                        if self.case.line(l) == line =>
                    {
                        Some(d)
                    }
                    _ => None,
                }
                .and_then(|d| {
                    let (a, b) = (ms(start).max(from), (ms(start) + ms(d)).min(to));
                    (b > a).then(|| b - a)
                })
            })
            .sum()
    }

    /// The longest host watchdog module `i` may have: configured, or set by the script.
    fn longest_watchdog(&self, i: usize) -> Duration {
        let configured = self.run.modules[i]
            .entries
            .iter()
            .filter_map(|e| self.case.rig.modules[*e].watchdog_tenths)
            .max()
            .map_or(Duration::ZERO, |t| ms(u64::from(t) * 100));
        let scripted = self
            .case
            .statements()
            .iter()
            .any(|s| matches!(s, Stmt::Watchdog { dev, .. } if self.addresses(i, *dev)));
        if scripted {
            configured.max(ms(2500))
        } else {
            configured
        }
    }

    /// The longest a failing exchange takes on the rig (all attempts, timeouts capped at 10 s).
    fn slowest_exchange(&self) -> Duration {
        self.case
            .rig
            .modules
            .iter()
            .map(|m| ms(m.timeout_ms.min(10_000)) * (u32::from(m.retries) + 1))
            .max()
            .unwrap_or_default()
    }

    /// When the last answer that answer fault `fault`, planned for `start`, acted on was
    /// given (`None`: it acted on none).
    fn last_hit(&self, start: u64, fault: InjectedFault) -> Option<Duration> {
        let (line, planned) = super::harness::answer_fault(fault)?;
        self.run
            .hits
            .get(&self.case.line(line))?
            .iter()
            .filter(|h| h.planned == ms(start) && h.fault == planned)
            .map(|h| h.at)
            .max()
    }

    /// The faults that could keep a watchdog from being fed around `t`. An answer fault counts
    /// from its start to the last answer it took, which can be long after its start: it acts
    /// on the next exchange that is answered (a Modbus feed gets no answer, so in an idle loop
    /// that is the output check every 5 s), and each answer it takes from a module already lost
    /// costs a retry a second. Until the module answers again it is left to its own watchdog
    /// (docs/design/verify.md, "The fault search").
    fn explains(&self, t: Duration, watchdog: Duration) -> Option<(u64, InjectedFault)> {
        let slow = self.slowest_exchange();
        let tail = ms(1000) + watchdog + ms(2 * self.case.rig.period_ms) + slow * 4;
        self.case.faults.iter().copied().find(|&(start, f)| {
            let lasts = match f {
                InjectedFault::Input { .. }
                | InjectedFault::Sigterm
                | InjectedFault::Kill
                | InjectedFault::ModuleReset { .. }
                | InjectedFault::Swap { .. }
                | InjectedFault::OutputStage { .. } => return false,
                InjectedFault::Freeze { ms: d }
                | InjectedFault::LinkStall { ms: d, .. }
                | InjectedFault::Silence { ms: d, .. }
                | InjectedFault::Unplug { ms: d, .. }
                | InjectedFault::Late { ms: d, .. } => ms(d),
                InjectedFault::Drop { answers, .. } => slow * u32::from(answers),
                InjectedFault::Flip { .. } | InjectedFault::Panic { .. } => slow,
            };
            let from = ms(start);
            let until = self.last_hit(start, f).map_or(from, |hit| hit.max(from));
            from <= t && t <= until + lasts + tail
        })
    }

    /// A watchdog that fires while the runner runs needs a fault to explain it: otherwise the
    /// runner did not feed it in time on its own (a period or exchange longer than it allows).
    fn spurious_watchdog(&mut self, i: usize) {
        let gone = self.runner_gone();
        let watchdog = self.longest_watchdog(i);
        let name = self.names(i);
        for c in self.history(i) {
            if c.cause != OutputCause::WatchdogFired || c.at >= gone {
                continue;
            }
            if self.explains(c.at, watchdog).is_none() {
                self.push(
                    "spurious-watchdog",
                    format!(
                        "{name}: its host watchdog fired at {} with the runner running and no \
                         fault to explain it (period {} ms, watchdog up to {})",
                        at(c.at),
                        self.case.rig.period_ms,
                        at(watchdog)
                    ),
                );
            }
        }
    }

    /// After a stall of the runner that let a module's watchdog fire, the script's outputs
    /// must be written again at once, not at the next periodic check.
    fn restore_after_stall(&mut self, i: usize) {
        if self.run.modules[i].entries.len() != 1 {
            return;
        }
        if let End::Ran { log, .. } = &self.run.end {
            let busy = ["error", "restart", "held at"];
            if log.iter().any(|l| busy.iter().any(|b| l.contains(b))) {
                return;
            }
        }
        // No other fault is near, so exchanges cost no time: the first tick after the stall
        // can see the module went safe and take control again.
        let settle = ms(2 * self.case.rig.period_ms + 200);
        let safes = self.safes(i);
        let history = self.history(i);
        let name = self.names(i);
        for &(start, fault) in &self.case.faults {
            let InjectedFault::Freeze { ms: d } = fault else {
                continue;
            };
            let (from, to) = (ms(start), ms(start) + ms(d));
            let by = to + settle;
            if self.runner_gone() <= by {
                continue;
            }
            let quiet = self.case.faults.iter().all(|&(t, f)| {
                (t, f) == (start, fault)
                    || matches!(f, InjectedFault::Input { .. })
                    || ms(t) + ms(3000) < from
                    || ms(t) > by
            });
            if !quiet || self.stage_faulty(i, from, by) {
                continue;
            }
            let Some(fired) = history
                .iter()
                .find(|c| c.cause == OutputCause::WatchdogFired && c.at >= from && c.at <= to)
            else {
                continue;
            };
            let wanted = history
                .iter()
                .rev()
                .find(|c| c.cause == OutputCause::HostWrite && c.at <= fired.at)
                .map(|c| c.after);
            if wanted.map_or(true, |w| safes.contains(&w)) {
                continue;
            }
            let restored = history
                .iter()
                .any(|c| c.cause == OutputCause::HostWrite && c.at > fired.at && c.at <= by);
            if !restored {
                let back = history
                    .iter()
                    .find(|c| c.cause == OutputCause::HostWrite && c.at > fired.at)
                    .map_or("never".into(), |c| at(c.at));
                self.push(
                    "late-restore",
                    format!(
                        "{name}: the runner stalled {} at {}; the module's watchdog fired at {} \
                         and its outputs stayed at the safe value until {back} (the stall was \
                         over at {}; allowed until {})",
                        at(ms(d)),
                        at(from),
                        at(fired.at),
                        at(to),
                        at(by)
                    ),
                );
            }
        }
    }

    /// When the run began to end: its "stopping" line, else its last error (an error end, a
    /// caught panic) before the end's own reports, else when it returned.
    fn end_began(&self) -> Duration {
        let End::Ran { log, .. } = &self.run.end else {
            return self.run.ended_at;
        };
        let ending = |l: &&String| l.contains(" error: ") && !l.contains(END_NOT_REACHED);
        log.iter()
            .rev()
            .find(|l| l.contains(" stopping: "))
            .or_else(|| log.iter().rev().find(ending))
            .and_then(|l| log_time(l))
            .unwrap_or(self.run.ended_at)
    }

    /// Whether the host could reach `line` all through the end of the run (the safe state is
    /// owed only to a module it could reach).
    fn reachable(&self, line: u8) -> bool {
        let (from, to) = (self.end_began(), self.run.ended_at);
        let down_meanwhile = self.case.faults.iter().any(|&(start, f)| match f {
            InjectedFault::Silence { line: l, ms: d }
            | InjectedFault::Unplug { line: l, ms: d } => {
                self.case.line(l) == line && ms(start) < to && ms(start) + ms(d) > from
            }
            _ => false,
        });
        self.run.killed_at.is_none()
            && !down_meanwhile
            && self.run.lines_at_end.get(&line).copied() == Some(Connection::Up)
    }

    fn end_state(&mut self) {
        let ran = matches!(self.run.end, End::Ran { .. } | End::Panicked);
        if !ran || self.cut_short() {
            return;
        }
        let how = match (&self.run.end, self.run.killed_at) {
            (_, Some(k)) => format!("killed at {}", at(k)),
            (End::Panicked, _) => format!("a panic at {}", at(self.run.ended_at)),
            _ => format!("the end at {}", at(self.run.ended_at)),
        };
        for (e, m) in self.case.rig.modules.iter().enumerate() {
            let Some(i) = self.run.module_of(e) else {
                continue;
            };
            let name = render::name(e);
            let now = self.run.at_end[i];
            let later = self.run.after_wait[i];
            let faulty = self.stage_faulty(i, self.end_began(), self.run.ended_at);
            // The runner checks its modules until its end begins (or it is gone).
            let unseen = self.swapped_unseen(i, self.end_began().min(self.runner_gone()));
            if self.reachable(m.line) {
                let said = match &self.run.end {
                    End::Ran { log, .. } => log
                        .iter()
                        .any(|l| l.contains(&format!("{name}{END_NOT_REACHED}"))),
                    _ => false,
                };
                if now.outputs != m.safe && faulty && !said {
                    self.push(
                        "end-unconfirmed-not-said",
                        format!(
                            "{name}: outputs {:#04x} after {how} (its output stage is faulty), \
                             and the end did not say it did not reach it",
                            now.outputs
                        ),
                    );
                } else if now.outputs != m.safe && !faulty {
                    let shared = self.run.modules[i].entries.len() > 1;
                    let skipped = match &self.run.end {
                        End::Ran { log, .. } => log.iter().any(|l| {
                            l.contains(" safe state (") && l.contains(&format!("{name} lost"))
                        }),
                        _ => false,
                    };
                    let kind = if shared {
                        "end-not-safe-shared-module"
                    } else if matches!(self.run.end, End::Panicked) {
                        "panic-not-safe"
                    } else if skipped {
                        "end-skipped-reachable"
                    } else {
                        "end-not-safe"
                    };
                    let why = if shared {
                        " (another rig.toml entry names the same module)"
                    } else if skipped {
                        " (the runner counted it lost and wrote nothing, but it answered again)"
                    } else {
                        ""
                    };
                    self.push(
                        kind,
                        format!(
                            "{name}: outputs {:#04x} after {how}; its safe value is {:#04x}{why}",
                            now.outputs, m.safe
                        ),
                    );
                }
                if now.safe_value != m.safe && !unseen {
                    self.push(
                        "safe-value-changed",
                        format!(
                            "{name}: the module's stored safe value is {:#04x} after {how}; \
                             rig.toml sets {:#04x}",
                            now.safe_value, m.safe
                        ),
                    );
                }
            }
            let Some(w) = m.watchdog_tenths else {
                continue;
            };
            if unseen {
                continue;
            }
            let wd = now.watchdog;
            // Off is fine once the outputs are safe; otherwise only the watchdog can make them so.
            if (wd.enabled && wd.timeout_tenths > w) || (!wd.enabled && now.outputs != m.safe) {
                self.push(
                    "watchdog-weakened",
                    format!(
                        "{name}: the module's host watchdog is {} after {how}; rig.toml sets \
                         {}.{} s",
                        if wd.enabled {
                            format!("{} tenths", wd.timeout_tenths)
                        } else {
                            "off".into()
                        },
                        w / 10,
                        w % 10
                    ),
                );
            }
            if later.outputs != m.safe {
                self.push(
                    "not-safe-after-end",
                    format!(
                        "{name}: outputs {:#04x} {} after {how} (modules on their own, \
                         unplugged ones back in); its safe value is {:#04x} and it has a {}.{} s \
                         watchdog",
                        later.outputs,
                        at(super::harness::AFTER_END_WAIT),
                        m.safe,
                        w / 10,
                        w % 10
                    ),
                );
            }
        }
    }

    /// Since when `line` has been down without a break, if it is down at `t`.
    fn down_since(&self, line: u8, t: Duration) -> Option<Duration> {
        let mut since: Option<Duration> = None;
        let mut intervals: Vec<(Duration, Duration)> = self
            .case
            .faults
            .iter()
            .filter_map(|&(start, f)| match f {
                InjectedFault::Silence { line: l, ms: d }
                | InjectedFault::Unplug { line: l, ms: d }
                    if self.case.line(l) == line =>
                {
                    Some((ms(start), ms(start) + ms(d)))
                }
                _ => None,
            })
            .collect();
        intervals.sort();
        for (a, b) in intervals {
            if a > t {
                break;
            }
            if b > t {
                since = Some(since.map_or(a, |s: Duration| s.min(a)));
            }
        }
        since
    }

    fn exit_status(&mut self) {
        if self.run.killed_at.is_some() || self.cut_short() {
            return;
        }
        let real_panics: Vec<&String> = self
            .run
            .panics
            .iter()
            .filter(|p| !p.starts_with(MEMORY_MARKER) && !p.starts_with(WORK_MARKER))
            .collect();
        match &self.run.end {
            End::StartFailed { status, message } => {
                let faulted = self.case.faults.iter().any(|&(t, f)| {
                    ms(t) <= self.run.ended_at && !matches!(f, InjectedFault::Input { .. })
                });
                let no_answer = message.contains("no answer") || message.contains("garbled");
                if *status == 3 && no_answer && !faulted {
                    self.push(
                        "exit-status",
                        format!("start failed with no fault to explain it: {message}"),
                    );
                }
            }
            End::Ran { status, log, .. } => {
                let status = *status;
                if let Some(p) = real_panics.first() {
                    if status != exit::INTERNAL {
                        self.push(
                            "exit-status",
                            format!(
                                "exit status {status} after a panic ({p}); a bug is {}",
                                exit::INTERNAL
                            ),
                        );
                    }
                    return;
                }
                let stopping = log.iter().rposition(|l| l.contains(" stopping: "));
                let Some(si) = stopping else {
                    if status != exit::ERROR {
                        self.push(
                            "exit-status",
                            format!("the run ended on an error but its exit status is {status}"),
                        );
                    }
                    return;
                };
                let line = &log[si];
                if let Some(code) = line
                    .split("the script called stop(")
                    .nth(1)
                    .and_then(|r| r.split(')').next())
                    .and_then(|c| c.parse::<i32>().ok())
                    .filter(|c| *c != 0)
                {
                    if status != code {
                        self.push(
                            "exit-status",
                            format!(
                                "the script called stop({code}) but the exit status is {status}"
                            ),
                        );
                    }
                    return;
                }
                let signal = line.contains(" received");
                if signal && self.run.sigterm_at.is_none() {
                    self.push(
                        "exit-status",
                        "the run says it got a signal, but none was sent".into(),
                    );
                }
                let script_error =
                    |l: &&String| l.contains(" error: in ") || l.contains(" error: case.rhai:");
                // Script errors the run went on after (skip, restart), and anything that failed
                // once it was stopping (on_stop, the safe state).
                // A write a module refused is a device fault the run must own up to.
                let refused = |l: &&String| {
                    l.contains(": writing outputs failed: ") && !l.contains("no answer")
                };
                let mut failures: Vec<String> = log[..si]
                    .iter()
                    .filter(|l| script_error(l) || refused(l))
                    .chain(log[si..].iter().filter(|l| l.contains(" error: ")))
                    .cloned()
                    .collect();
                let grace = ms(self.case.rig.grace_ms);
                for line in self.case.lines() {
                    if let Some(since) = self.down_since(line, self.run.ended_at) {
                        if self.run.ended_at.saturating_sub(since) > grace {
                            failures.push(format!(
                                "line {line} lost since {} and not back at the end",
                                at(since)
                            ));
                        }
                    }
                }
                let clean = if signal {
                    exit::signal(SIGTERM)
                } else {
                    exit::OK
                };
                // A device the runner saw lost may count as trouble even if it answered the end.
                let saw_loss = log.iter().any(|l| l.contains(": lost: "));
                let accepted = status == clean || (saw_loss && status == exit::TROUBLE);
                if failures.is_empty() && !accepted {
                    self.push(
                        "exit-status",
                        format!(
                            "exit status {status} after a clean end ({line}); expected {clean}"
                        ),
                    );
                }
                if !failures.is_empty() && (status == exit::OK || status == clean) {
                    self.push(
                        "exit-hides-failure",
                        format!(
                            "exit status {status} after a failure: {}",
                            failures.join("; ")
                        ),
                    );
                }
            }
            End::Panicked | End::ConfigRefused(_) => {}
        }
    }

    /// Whether a reading of module `i` recorded at `t` may have come from an answer a `Flip`
    /// took, on a protocol that cannot tell: ASCII without checksums (the search's modules have
    /// none) reads a hex digit flipped into another hex digit as a well-formed value. Such an
    /// answer was given in the tick that recorded the reading, at most a tick's exchanges before.
    fn flipped_unchecked(&self, i: usize, t: Duration) -> bool {
        let m = &self.run.modules[i];
        let ascii = m
            .entries
            .iter()
            .any(|e| self.case.rig.modules[*e].protocol == Proto::Ascii);
        let tick = ms(self.case.rig.period_ms) + self.slowest_exchange() * 4;
        ascii
            && self.run.hits.get(&m.line).is_some_and(|hits| {
                hits.iter().any(|h| {
                    matches!(h.fault, LinkFault::Flip { .. }) && h.at <= t && h.at + tick >= t
                })
            })
    }

    /// Whether a reading of module `i` recorded at `t` may have come from an answer that a
    /// `Late` made later than the module's timeout and the settling silence after it (one
    /// timeout) together, over ASCII: such an answer gets past the settle and lands in a later
    /// exchange, and an ASCII counter or latch answer does not say which channel it is for, so
    /// nothing on the line can tell it from that exchange's own (docs/benchmarks.md, "Line timing"). It
    /// arrives at the hit plus its delay, and is read in the tick that recorded the reading.
    fn answered_too_late(&self, i: usize, t: Duration) -> bool {
        let m = &self.run.modules[i];
        let Some(timeout) = m
            .entries
            .iter()
            .map(|e| &self.case.rig.modules[*e])
            .filter(|e| e.protocol == Proto::Ascii)
            .map(|e| ms(e.timeout_ms))
            .min()
        else {
            return false;
        };
        let tick = ms(self.case.rig.period_ms) + self.slowest_exchange() * 4;
        self.run.hits.get(&m.line).is_some_and(|hits| {
            hits.iter().any(|h| match h.fault {
                LinkFault::Late(d) if d > timeout * 2 => {
                    let arrives = h.at + d;
                    arrives <= t && t <= arrives + tick
                }
                _ => false,
            })
        })
    }

    /// What the script recorded of the inputs must be what the field put on them by then, and
    /// no counter may show more edges than the field made on its channel; a reading from an
    /// answer flipped into another well-formed one, or from one later than the timeout and the
    /// settle together, is not held against the runner where the protocol cannot tell.
    fn inputs(&mut self) {
        let End::Ran { records, .. } = &self.run.end else {
            return;
        };
        let origin = chrono::DateTime::parse_from_rfc3339("2026-01-05T00:00:00Z")
            .map(|t| t.to_utc())
            .unwrap_or_default();
        let mut wrong = Vec::new();
        for r in records {
            let (Some(name), Some(value), Some(time)) = (
                r.get("name").and_then(|v| v.as_str()),
                r.get("value"),
                r.get("time").and_then(|v| v.as_str()),
            ) else {
                continue;
            };
            let (dev, counters) = match name.strip_suffix(".counters") {
                Some(dev) => (dev, true),
                None => (name, false),
            };
            let Some(entry) = dev.strip_prefix("io").and_then(|n| n.parse::<usize>().ok()) else {
                continue;
            };
            let Some(i) = self.run.module_of(entry) else {
                continue;
            };
            let Ok(t) = chrono::DateTime::parse_from_rfc3339(time) else {
                continue;
            };
            let t = (t.to_utc() - origin).to_std().unwrap_or_default() + ms(1);
            if self.flipped_unchecked(i, t) || self.answered_too_late(i, t) {
                continue;
            }
            let field: Vec<u8> = self.run.modules[i]
                .inputs
                .iter()
                .filter(|(when, _)| *when <= t)
                .map(|(_, v)| *v)
                .collect();
            if counters {
                let read: Vec<i64> = value
                    .as_array()
                    .map(|a| a.iter().filter_map(serde_json::Value::as_i64).collect())
                    .unwrap_or_default();
                for (ch, count) in read.iter().enumerate() {
                    let edges = edges(&field, ch);
                    if *count > edges {
                        wrong.push(format!(
                            "{name}[{ch}] read {count} at {time}, but the field changed DI{ch} \
                             only {edges} time(s) by then"
                        ));
                    }
                }
            } else if let Some(v) = value.as_i64() {
                if !field.iter().any(|f| i64::from(*f) == v) {
                    wrong.push(format!(
                        "{name} inputs read {v:#04x} at {time}, a value the field never put on them"
                    ));
                }
            }
        }
        if let Some(first) = wrong.first() {
            self.push(
                "wrong-input",
                format!("{first} ({} such readings)", wrong.len()),
            );
        }
    }

    /// Script errors must say where in the script they happened.
    fn error_locations(&mut self) {
        let End::Ran { log, .. } = &self.run.end else {
            return;
        };
        if let Some(line) = log.iter().find(|l| l.contains(" error: in ")) {
            self.push(
                "error-without-location",
                format!("a script error without file:line:column: {line}"),
            );
        }
    }
}

/// The virtual time of a log line (`HH:MM:SS.mmm ...`; the search's wall clock starts at
/// midnight).
fn log_time(line: &str) -> Option<Duration> {
    let stamp = line.get(..12)?;
    let mut parts = stamp.split([':', '.']);
    let mut next = || parts.next().and_then(|p| p.parse::<u64>().ok());
    let (h, m, sec, milli) = (next()?, next()?, next()?, next()?);
    Some(ms(((h * 60 + m) * 60 + sec) * 1000 + milli))
}

/// How many times channel `ch` changed in the DI bytes `field` (either edge: an upper bound on
/// what its counter can have counted, whichever edge it counts).
fn edges(field: &[u8], ch: usize) -> i64 {
    let bit = 1u8 << ch;
    let changes = field
        .windows(2)
        .filter(|w| (w[0] ^ w[1]) & bit != 0)
        .count();
    i64::try_from(changes).unwrap_or(i64::MAX)
}
