//! `verify --exhaustive`: every sequence of up to K choices from a finite vocabulary, breadth
//! first, so the first violation found is a shortest one. A choice is a field event (an input,
//! switch or rotary the script reads worked; a counter it compares carried to a compared value,
//! one below or one above; a device lost or back; with faults, a stall past the grace time or a
//! watchdog, a wall-clock step to the next cron time or back by its period), each followed by
//! one scan, or a wait to the next boundary of the script's own time (a scan, each pending
//! timer's next firing, a lost device's grace time). Runs are deterministic, so a state is
//! reached again by replaying its choices from the start; states found equal (`fingerprint`)
//! at the same instant are explored once. No seed: the same script gives the same result.

use super::checks::Finding;
use super::exec::{begin, ExecError, Keep, Player, Step, Target};
use super::field::{next_cron, BASE_START};
use super::plan::{Action, Event, StartPoint};
use super::profile::{Kind, Profile};
use crate::protocol::trc1000::{Rotary, Switch};
use crate::runtime::devices::Device;
use crate::runtime::handlers::Source;
use crate::runtime::schedule::TimerKind;
use crate::script::reads::Item;
use crate::time::clock::Clock;
use crate::time::duration::format_duration;
use chrono::{DateTime, Utc};
use std::collections::{BTreeSet, HashSet};
use std::hash::{DefaultHasher, Hash, Hasher};
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// The depth explored unless `--depth` says otherwise.
pub const DEFAULT_DEPTH: usize = 4;

/// How long before its first cron time a script with a cron schedule starts (so that the
/// schedule's first firing is one short wait away, not minutes of replayed scans).
const BEFORE_CRON: Duration = Duration::from_secs(1);

/// What the abstraction leaves out, as the report says it.
pub const ABSTRACTED: [&str; 5] = [
    "values: counters only at the values the script compares them with, one below and one \
     above (carried there in one scan, or that many pulses from where they are); rotaries a \
     half-turn or a detent each way and to the values compared with",
    "time: an event is followed by one scan; waiting goes to the next scan, the next firing of \
     each pending timer, or past a lost device's grace time, not to the instants between",
    "faults: a device lost and back, a stall past the grace time or a watchdog, the wall clock \
     to the next cron time or back by its period; not lost, garbled, late or doubled answers, \
     power cycles or stop signals (the end of the run is checked after every sequence)",
    "start: one start (2026-03-28 12:00 UTC, or a second before the first cron time after it), \
     all inputs released and counters at zero",
    "states are merged only at the same instant and with no fault behind them",
];

/// How an exhaustive search is run.
#[derive(Debug, Clone)]
pub struct Options {
    /// Choices per sequence at most.
    pub depth: usize,
    /// Worker threads.
    pub jobs: usize,
    /// Faults in the vocabulary.
    pub faults: bool,
    /// Set (to a signal's number) to stop at the next state.
    pub interrupt: Option<Arc<AtomicUsize>>,
}

/// One choice: an action now (none for a wait), then the run advanced to `until`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Choice {
    /// What happens now.
    pub action: Option<Action>,
    /// The instant (since the start) the run is advanced to afterwards.
    pub until: Duration,
    /// A wait's reason, in words (`its 75s timer`).
    pub wait: Option<String>,
}

/// A violation found: the shortest sequence that shows it.
#[derive(Debug, Clone)]
pub struct Found {
    /// The choices.
    pub choices: Vec<Choice>,
    /// Its events (the waits are in their times).
    pub events: Vec<Event>,
    /// What failed.
    pub finding: Finding,
    /// The steps, for the test file.
    pub steps: Vec<Step>,
}

/// What an exhaustive search came to.
#[derive(Debug, Clone)]
pub struct Summary {
    /// The depth asked for.
    pub depth: usize,
    /// Depths explored whole (all sequences of up to this many choices).
    pub complete: usize,
    /// Distinct states explored.
    pub states: u64,
    /// Sequences played (each from the start).
    pub sequences: u64,
    /// Sequences whose state was one already explored.
    pub merged: u64,
    /// Where every sequence starts.
    pub start: StartPoint,
    /// The vocabulary, in words.
    pub vocabulary: Vec<String>,
    /// The violation, if one was found.
    pub found: Option<Found>,
    /// Stopped by a signal.
    pub interrupted: bool,
    /// Wall time.
    pub time: Duration,
}

/// What each device offers as choices.
#[derive(Debug, Clone)]
struct DeviceChoices {
    name: Arc<str>,
    kind: Kind,
    /// Inputs the script reads (bit n = DIn).
    inputs: u8,
    /// Counter channel → the values compared with.
    counters: Vec<(u8, Vec<u16>)>,
    switches: Vec<Switch>,
    /// Rotary → the values compared with.
    rotaries: Vec<(Rotary, Vec<u8>)>,
}

/// The vocabulary of one script on its rig.
#[derive(Debug, Clone)]
struct Vocabulary {
    devices: Vec<DeviceChoices>,
    faults: bool,
    period: Duration,
    grace: Duration,
    /// States may be merged (off when two devices share a kind: a script's handle to one
    /// shows as the kind's name only).
    merge: bool,
    /// The script has a cron schedule (wall-clock steps are worth a choice).
    cron: bool,
}

impl Vocabulary {
    fn new(profile: &Profile, faults: bool) -> Self {
        let modules = profile
            .devices
            .iter()
            .filter(|d| d.kind == Kind::C29u)
            .count();
        let panels = profile.devices.len() - modules;
        let devices = profile
            .devices
            .iter()
            .enumerate()
            .map(|(idx, d)| {
                let reads = |item| profile.reads.contains(idx, item);
                let mut c = DeviceChoices {
                    name: Arc::clone(&d.name),
                    kind: d.kind,
                    inputs: 0,
                    counters: Vec::new(),
                    switches: Vec::new(),
                    rotaries: Vec::new(),
                };
                match d.kind {
                    Kind::C29u => {
                        for ch in 0..8 {
                            if reads(Item::Input(ch)) {
                                c.inputs |= 1 << ch;
                            }
                            let marks = profile.facts.counter_values(ch);
                            if !marks.is_empty() && (modules == 1 || reads(Item::Counter(ch))) {
                                c.counters.push((ch, marks));
                            }
                        }
                    }
                    Kind::Trc => {
                        c.switches = Switch::all().filter(|s| reads(Item::Switch(*s))).collect();
                        c.rotaries = Rotary::ALL
                            .into_iter()
                            .filter(|r| reads(Item::Rotary(*r)))
                            .map(|r| (r, profile.facts.rotary_values(r)))
                            .collect();
                    }
                }
                c
            })
            .collect();
        Self {
            devices,
            faults,
            period: profile.period,
            grace: profile.grace,
            merge: modules <= 1 && panels <= 1,
            cron: !profile.crons.is_empty(),
        }
    }

    /// The vocabulary in words.
    fn describe(&self) -> Vec<String> {
        let mut out = Vec::new();
        for d in &self.devices {
            for ch in (0..8).filter(|ch| d.inputs & (1 << ch) != 0) {
                out.push(format!("{} DI{ch} on/off", d.name));
            }
            if d.inputs.count_ones() > 1 {
                out.push(format!(
                    "{} inputs {:#04x} all on/all off",
                    d.name, d.inputs
                ));
            }
            for (ch, marks) in &d.counters {
                let marks: Vec<String> = marks.iter().map(u16::to_string).collect();
                out.push(format!(
                    "{} counter DI{ch} to {} (each, one below, one above)",
                    d.name,
                    marks.join(", ")
                ));
            }
            for s in &d.switches {
                out.push(format!("{} {s} pressed/released", d.name));
            }
            for (r, _) in &d.rotaries {
                out.push(format!("{} {} turned", d.name, r.name()));
            }
            if self.faults {
                out.push(format!("{} lost/back", d.name));
            }
        }
        if self.faults {
            out.push("host stalled past the grace time or a watchdog".into());
        }
        if self.faults && self.cron {
            out.push("wall clock to the next cron time or back by its period".into());
        }
        out.push("wait: a scan, each timer's next firing, a lost device's grace time".into());
        out
    }

    /// The choices from the state `p` is in, in a fixed order.
    fn choices(&self, p: &Player) -> Vec<Choice> {
        let now = p.clock.now();
        let tick = now + self.period;
        let mut out: Vec<Choice> = Vec::new();
        let mut act = |action: Action, until: Duration| {
            let c = Choice {
                action: Some(action),
                until,
                wait: None,
            };
            if !out.contains(&c) {
                out.push(c);
            }
        };
        let sim = &p.rig.sim;
        for d in &self.devices {
            let dev = || Arc::clone(&d.name);
            match d.kind {
                Kind::C29u => {
                    let Ok(model) = sim.c29u(&d.name, "explore") else {
                        continue;
                    };
                    let (levels, counts) = {
                        let m = crate::sync::lock(&model);
                        (m.inputs(), m.counters())
                    };
                    for ch in (0..8).filter(|ch| d.inputs & (1 << ch) != 0) {
                        let on = levels & (1 << ch) == 0;
                        act(Action::Input { dev: dev(), ch, on }, tick);
                    }
                    if d.inputs.count_ones() > 1 {
                        for byte in [levels | d.inputs, levels & !d.inputs] {
                            if (byte ^ levels).count_ones() > 1 {
                                act(Action::Inputs { dev: dev(), byte }, tick);
                            }
                        }
                    }
                    for (ch, marks) in &d.counters {
                        let now_count = counts.get(usize::from(*ch)).copied().unwrap_or(0);
                        let mut reached = BTreeSet::new();
                        let near = |m: u16| [m.saturating_sub(1), m, m.saturating_add(1)];
                        for value in marks.iter().flat_map(|m| near(*m)) {
                            if value > now_count && reached.insert(value) {
                                act(
                                    Action::CounterTo {
                                        dev: dev(),
                                        ch: *ch,
                                        value,
                                    },
                                    tick,
                                );
                            }
                        }
                        // Counts since a baseline: as many pulses from where it is.
                        for n in marks.iter().flat_map(|m| near(*m)) {
                            let to = now_count.wrapping_add(n);
                            if n > 0 && now_count > 0 && reached.insert(to) {
                                act(
                                    Action::Pulse {
                                        dev: dev(),
                                        ch: *ch,
                                        n: u32::from(n),
                                    },
                                    tick,
                                );
                            }
                        }
                    }
                }
                Kind::Trc => {
                    let Ok(panel) = sim.trc(&d.name, "explore") else {
                        continue;
                    };
                    let (pressed, values) = {
                        let t = crate::sync::lock(&panel);
                        (t.switches(), t.rotaries())
                    };
                    for s in &d.switches {
                        let action = if pressed.is_pressed(*s) {
                            Action::Release {
                                dev: dev(),
                                switch: *s,
                            }
                        } else {
                            Action::Press {
                                dev: dev(),
                                switch: *s,
                            }
                        };
                        act(action, tick);
                    }
                    for (r, compared) in &d.rotaries {
                        let at = i32::from(values.get(*r));
                        let to_values = compared.iter().map(|v| {
                            let delta = (i32::from(*v) - at).rem_euclid(256);
                            if delta > 128 {
                                delta - 256
                            } else {
                                delta
                            }
                        });
                        for half_turns in [1, -1, 2, -2].into_iter().chain(to_values) {
                            if half_turns != 0 {
                                act(
                                    Action::Turn {
                                        dev: dev(),
                                        rotary: *r,
                                        half_turns,
                                    },
                                    tick,
                                );
                            }
                        }
                    }
                }
            }
            if self.faults {
                let action = if sim.answers(&d.name).unwrap_or(true) {
                    Action::Fail { dev: dev() }
                } else {
                    Action::Restore { dev: dev() }
                };
                act(action, tick);
            }
        }
        let rt = p.rig.runner.runtime().borrow();
        let wall = p.clock.wall();
        if self.faults {
            let mut stalls = vec![self.grace + self.period];
            for d in rt.devices() {
                if let Device::C29u(c) = d {
                    if let Some(w) = c.watchdog() {
                        stalls.push(w.as_duration() + self.period);
                    }
                }
            }
            for by in stalls {
                act(Action::Stall { by }, now + by + self.period);
            }
            for r in rt.handlers().list() {
                if let Source::Timer(id) = r.source {
                    if let Some(TimerKind::Cron(expr)) = rt.handlers().timer_kind(id) {
                        let crons = BTreeSet::from([expr.clone()]);
                        let Some(next) = next_cron(&crons, wall, crate::time::zone::Zone::utc())
                        else {
                            continue;
                        };
                        let ahead = (next - wall).num_milliseconds();
                        let seconds = (ahead + 999) / 1000;
                        act(Action::WallStep { seconds }, tick);
                        if let Some(after) = next_cron(&crons, next, crate::time::zone::Zone::utc())
                        {
                            let back = (after - next).num_seconds();
                            act(Action::WallStep { seconds: -back }, tick);
                        }
                    }
                }
            }
        }
        // Waits: a scan, each timer's next firing, past each lost device's grace time.
        let mut waits: Vec<(Duration, String)> = vec![(tick, "a scan".into())];
        // The runner's own next wake-up (an idle loop sleeps to its timers and device checks).
        let wake = p.rig.runner.next_deadline();
        if wake > tick {
            waits.push((wake, "the runner's next tick".into()));
        }
        let seen = p.timers_seen.as_ref();
        for r in rt.handlers().list() {
            let Source::Timer(id) = r.source else {
                continue;
            };
            let since = seen.and_then(|s| s.get(&r.id)).copied().unwrap_or(now);
            let next = match rt.handlers().timer_kind(id) {
                Some(TimerKind::Every(d)) if !d.is_zero() => {
                    let n = (now.saturating_sub(since).as_nanos() / d.as_nanos()) + 1;
                    since + d.saturating_mul(u32::try_from(n).unwrap_or(u32::MAX))
                }
                Some(TimerKind::After(d)) => since + *d,
                Some(TimerKind::Cron(expr)) => {
                    let crons = BTreeSet::from([expr.clone()]);
                    match next_cron(&crons, wall, crate::time::zone::Zone::utc()) {
                        Some(t) => now + (t - wall).to_std().unwrap_or_default(),
                        None => continue,
                    }
                }
                _ => continue,
            };
            if next > tick {
                waits.push((next, format!("{}'s next firing", r.label)));
            }
        }
        for d in rt.devices() {
            if let Some(lost) = d.health().lost_at() {
                let past = lost + self.grace + self.period;
                if past > tick {
                    waits.push((past, format!("{}'s grace time", d.name())));
                }
            }
        }
        waits.sort_by_key(|w| w.0);
        waits.dedup_by_key(|w| w.0);
        out.extend(waits.into_iter().map(|(until, why)| Choice {
            action: None,
            until,
            wait: Some(why),
        }));
        out
    }
}

/// A hash of everything of the state `p` is in that decides what comes next, as far as verify
/// can see it: the instant and the wall clock, each device as the runner has it (health,
/// readings with the ones before, wanted outputs, watchdog) and as its simulator has it,
/// every handler with what it waits for (a counter's arming) and the values its closure
/// captured (the script's variables), each timer with when it was set, the invariants
/// likewise. `history` is hashed in too (the choices behind a state with a fault in it).
fn fingerprint(p: &Player, history: Option<&[Choice]>) -> u128 {
    let mut text = String::new();
    use std::fmt::Write;
    let rt = p.rig.runner.runtime().borrow();
    let _ = write!(
        text,
        "{:?}|{}|{:?}|{}|{}|",
        p.clock.now(),
        p.clock.wall().timestamp_millis(),
        p.rig.runner.status(),
        rt.held_safe(),
        rt.program().polls_inputs()
    );
    for d in rt.devices() {
        let _ = write!(text, "{}:{:?}", d.name(), d.health());
        match d {
            Device::C29u(c) => {
                let _ = write!(
                    text,
                    "{:?}{:?}{:?}{}{:?}{:?}",
                    c.inputs(),
                    c.counters(),
                    c.latches(),
                    c.wanted_outputs(),
                    c.watchdog(),
                    c.outputs_written()
                );
            }
            Device::Trc(t) => {
                let _ = write!(
                    text,
                    "{:?}{:?}{}",
                    t.switches(),
                    t.rotaries(),
                    t.wanted_relay()
                );
            }
        }
        let sim = &p.rig.sim;
        let _ = write!(text, "{:?}", sim.answers(d.name()));
        if let Ok(m) = sim.c29u(d.name(), "fingerprint") {
            let m = crate::sync::lock(&m);
            let _ = write!(
                text,
                "{}{}{:?}{}{}{:?}",
                m.outputs(),
                m.inputs(),
                m.counters(),
                m.latched_low(),
                m.latched_high(),
                m.eeprom()
            );
        }
        if let Ok(w) = sim.watchdog(d.name()) {
            let _ = write!(text, "{w:?}");
        }
        if let Ok(t) = sim.trc(d.name(), "fingerprint") {
            let t = crate::sync::lock(&t);
            let _ = write!(text, "{:?}{:?}{:?}", t.relay(), t.switches(), t.rotaries());
        }
        text.push('|');
    }
    for r in rt.handlers().list() {
        let _ = write!(text, "{}:{:?}:{:?}", r.id, r.source, r.handler);
        if let Source::Timer(id) = r.source {
            let since = p.timers_seen.as_ref().and_then(|s| s.get(&r.id));
            let _ = write!(text, "{:?}{since:?}", rt.handlers().timer_kind(id));
        }
        text.push('|');
    }
    for i in rt.invariants() {
        let _ = write!(text, "{}:{:?}|", i.name, i.call.handler);
    }
    if let Some(h) = history {
        let _ = write!(text, "{h:?}");
    }
    let half = |salt: u64| {
        let mut hasher = DefaultHasher::new();
        salt.hash(&mut hasher);
        text.hash(&mut hasher);
        hasher.finish()
    };
    (u128::from(half(1)) << 64) | u128::from(half(2))
}

/// Where every sequence starts: `BASE_START`, or `BEFORE_CRON` before the first cron time
/// after it.
fn start_point(profile: &Profile) -> StartPoint {
    let base: DateTime<Utc> = DateTime::parse_from_rfc3339(BASE_START)
        .map(|t| t.to_utc())
        .unwrap_or_default();
    let zone = crate::time::zone::Zone::utc();
    let wall = next_cron(&profile.crons, base, zone)
        .and_then(|t| chrono::TimeDelta::from_std(BEFORE_CRON).ok().map(|b| t - b))
        .unwrap_or(base);
    StartPoint {
        wall: wall.fixed_offset(),
        zone: "UTC".into(),
    }
}

/// What playing one sequence came to.
enum Played {
    /// A check failed.
    Failed(Found),
    /// No finding: the state's fingerprint and the choices from it.
    State(u128, Vec<Choice>),
}

/// Plays `choices` from the start; stops at a finding.
fn play(
    target: &Target,
    start: &StartPoint,
    vocabulary: &Vocabulary,
    choices: &[Choice],
) -> Result<Played, ExecError> {
    let _ends = crate::guardian::pulse::EndsLoop;
    let keep = Keep {
        coverage: false,
        observe: false,
    };
    let mut p = begin(target, start, keep)?;
    p.timers_seen = Some(Default::default());
    let mut events = Vec::new();
    let failed = |p: Player, finding: Finding, events: Vec<Event>, upto: usize| {
        let steps = p.finish(Some(finding.clone()), 0).steps;
        Played::Failed(Found {
            choices: choices.get(..upto).unwrap_or(choices).to_vec(),
            events,
            finding,
            steps,
        })
    };
    if let Some(f) = p.first_finding() {
        return Ok(failed(p, f, events, 0));
    }
    if let Some(f) = p.advance_to(Duration::ZERO) {
        return Ok(failed(p, f, events, 0));
    }
    for (i, c) in choices.iter().enumerate() {
        if p.rig.runner.status().is_some() {
            break;
        }
        if let Some(a) = &c.action {
            events.push(Event {
                at: p.clock.now(),
                action: a.clone(),
            });
            p.apply(a)?;
        }
        let until = c.until.max(p.clock.now());
        if let Some(f) = p.advance_to(until) {
            return Ok(failed(p, f, events, i + 1));
        }
    }
    let faulty = choices
        .iter()
        .any(|c| c.action.as_ref().is_some_and(Action::is_fault));
    let fp = if vocabulary.merge {
        fingerprint(&p, faulty.then_some(choices))
    } else {
        fingerprint(&p, Some(choices))
    };
    let next = if p.rig.runner.status().is_some() {
        Vec::new()
    } else {
        vocabulary.choices(&p)
    };
    // The run ended here: what must hold after the end.
    let ended = p.end();
    if let Some(f) = ended.finding {
        return Ok(Played::Failed(Found {
            choices: choices.to_vec(),
            events,
            finding: f,
            steps: ended.steps,
        }));
    }
    Ok(Played::State(fp, next))
}

/// Plays every sequence of `level` (in `jobs` threads); the results in the level's order.
fn play_level(
    target: &Target,
    start: &StartPoint,
    vocabulary: &Vocabulary,
    level: &[Vec<Choice>],
    opts: &Options,
) -> Vec<Option<Result<Played, ExecError>>> {
    let next = AtomicUsize::new(0);
    let lowest_failure = AtomicUsize::new(usize::MAX);
    let results: Mutex<Vec<Option<Result<Played, ExecError>>>> =
        Mutex::new((0..level.len()).map(|_| None).collect());
    let stopped = || {
        opts.interrupt
            .as_ref()
            .is_some_and(|i| i.load(Ordering::Relaxed) != 0)
    };
    let work = || loop {
        let i = next.fetch_add(1, Ordering::SeqCst);
        let Some(choices) = level.get(i) else {
            break;
        };
        if stopped() || i > lowest_failure.load(Ordering::SeqCst) {
            break;
        }
        let r = play(target, start, vocabulary, choices);
        if matches!(r, Ok(Played::Failed(_)) | Err(_)) {
            lowest_failure.fetch_min(i, Ordering::SeqCst);
        }
        if let Some(slot) = crate::sync::lock(&results).get_mut(i) {
            *slot = Some(r);
        }
    };
    let stack = crate::script::stack::size_for(target.config.limits.memory);
    std::thread::scope(|s| {
        for _ in 0..opts.jobs.max(1) {
            let worker = std::thread::Builder::new().stack_size(stack);
            let watched = || crate::guardian::lone::watched("rigscript verify", work);
            if worker.spawn_scoped(s, watched).is_err() {
                work();
            }
        }
    });
    results.into_inner().unwrap_or_else(|e| e.into_inner())
}

/// Explores `target` breadth first to `opts.depth`; `progress` hears each depth done and
/// the states so far.
pub fn explore(
    target: &Target,
    opts: &Options,
    mut progress: impl FnMut(usize, u64),
) -> Result<Summary, ExecError> {
    let began = Instant::now();
    let mut profile = Profile::new(
        &target.config,
        &target.source,
        target.config.period,
        target.run_for,
    );
    learn_reads(target, &mut profile);
    let vocabulary = Vocabulary::new(&profile, opts.faults);
    let start = start_point(&profile);
    let mut summary = Summary {
        depth: opts.depth,
        complete: 0,
        states: 0,
        sequences: 0,
        merged: 0,
        start: start.clone(),
        vocabulary: vocabulary.describe(),
        found: None,
        interrupted: false,
        time: Duration::ZERO,
    };
    let mut seen: HashSet<u128> = HashSet::new();
    let mut level: Vec<Vec<Choice>> = vec![Vec::new()];
    for depth in 0..=opts.depth {
        // Fewest events first, so that the first violation of this depth has the fewest.
        level.sort_by_key(|l| l.iter().filter(|c| c.action.is_some()).count());
        let results = play_level(target, &start, &vocabulary, &level, opts);
        let mut next_level = Vec::new();
        let mut found: Option<Found> = None;
        for (choices, r) in level.iter().zip(results) {
            let Some(r) = r else {
                // Not played: after a violation of this depth, or stopped by a signal.
                summary.interrupted = found.is_none();
                break;
            };
            summary.sequences += 1;
            match r? {
                Played::Failed(f) => {
                    found = Some(f);
                    break;
                }
                Played::State(fp, next) => {
                    if !seen.insert(fp) {
                        summary.merged += 1;
                        continue;
                    }
                    summary.states += 1;
                    if depth < opts.depth {
                        for c in next {
                            let mut longer = choices.clone();
                            longer.push(c);
                            next_level.push(longer);
                        }
                    }
                }
            }
        }
        if found.is_some() {
            summary.found = found;
            summary.time = began.elapsed();
            return Ok(summary);
        }
        if summary.interrupted {
            break;
        }
        summary.complete = depth;
        progress(depth, summary.states);
        level = next_level;
        if level.is_empty() {
            break;
        }
    }
    summary.time = began.elapsed();
    Ok(summary)
}

/// What the script reads, from a run with no events and from the runs every search plays
/// first (each item worked once), so that the vocabulary holds what its handlers read too.
fn learn_reads(target: &Target, profile: &mut Profile) {
    let probe_target = Target {
        run_for: Duration::from_secs(2).min(target.run_for),
        ..target.clone()
    };
    let keep = Keep {
        coverage: false,
        observe: true,
    };
    let start = start_point(profile);
    let quiet = super::plan::Plan {
        start: start.clone(),
        events: Vec::new(),
    };
    if let Ok(seen) = super::exec::execute(&probe_target, &quiet, keep) {
        profile.learn(&seen.observed);
    }
    for mut plan in super::systematic::plans(profile, 0, false) {
        plan.start = start.clone();
        let t = Target {
            run_for: plan
                .events
                .last()
                .map_or(Duration::ZERO, |e| e.at)
                .saturating_add(profile.period.saturating_mul(3)),
            ..target.clone()
        };
        if let Ok(seen) = super::exec::execute(&t, &plan, keep) {
            profile.learn(&seen.observed);
        }
    }
}

/// The summary's result line: the violation's, or the proof's.
pub fn result_line(s: &Summary) -> String {
    match &s.found {
        Some(f) => format!(
            "shortest counterexample: {} choice(s), {} event(s): {}",
            f.choices.len(),
            f.events.len(),
            f.finding.check
        ),
        None if s.interrupted => format!(
            "interrupted: no violation in any sequence of up to {} events ({} states) before \
             the signal",
            s.complete, s.states
        ),
        None => format!(
            "no violation in any sequence of up to {} events ({} states)",
            s.complete, s.states
        ),
    }
}

/// A choice in words: the event, or what a wait waits for.
pub fn choice_text(c: &Choice) -> String {
    match (&c.action, &c.wait) {
        (Some(a), _) => a.to_string(),
        (None, Some(w)) => format!("wait for {w}"),
        (None, None) => format!("wait to {}", format_duration(c.until)),
    }
}

#[cfg(test)]
mod tests;
