//! Coverage, so a pass means something: how often each handler fired, how often the values
//! each invariant reads changed, which values the script reads never changed at all, and the
//! range each counter and rotary went through against the values the script compares it with.
//! A handler that never fired, an invariant whose values never changed or a value compared with
//! that its counter or rotary never reached is a warning.

use crate::protocol::trc1000::{Rotary, Switch};
use crate::runtime::device_view::{DeviceView, ModuleView, PanelView};
use crate::script::reads::{Item, ReadSet};
use crate::script::rig::Rig;
use serde_json::{json, Value};
use std::collections::{BTreeMap, BTreeSet};

/// The items of `now` that differ from `before`, as a mask (a device does not change kind).
fn changed(now: &DeviceView, before: &DeviceView) -> u128 {
    let mut m = 0u128;
    match (now, before) {
        (DeviceView::Trc(now), DeviceView::Trc(before)) => {
            if now.switches != before.switches {
                let (a, b) = (
                    before.switches.unwrap_or_default(),
                    now.switches.unwrap_or_default(),
                );
                for s in Switch::all() {
                    if a.is_pressed(s) != b.is_pressed(s) {
                        m |= Item::Switch(s).mask();
                    }
                }
            }
            if now.rotaries != before.rotaries {
                let (a, b) = (
                    before.rotaries.unwrap_or_default(),
                    now.rotaries.unwrap_or_default(),
                );
                for r in Rotary::ALL {
                    if a.get(r) != b.get(r) {
                        m |= Item::Rotary(r).mask();
                    }
                }
            }
            if now.relay != before.relay {
                m |= Item::Relay.mask();
            }
        }
        (DeviceView::C29u(now), DeviceView::C29u(before)) => {
            if now.inputs != before.inputs {
                let diff = now.inputs.unwrap_or(0) ^ before.inputs.unwrap_or(0);
                for ch in 0..8u8 {
                    if diff & (1 << ch) != 0 {
                        m |= Item::Input(ch).mask();
                    }
                }
            }
            if now.counters != before.counters {
                let (a, b) = (
                    before.counters.unwrap_or([0; 8]),
                    now.counters.unwrap_or([0; 8]),
                );
                for (ch, (x, y)) in (0u8..).zip(a.iter().zip(b.iter())) {
                    if x != y {
                        m |= Item::Counter(ch).mask();
                    }
                }
            }
            if now.latches != before.latches {
                m |= Item::Latches.mask();
            }
            if now.outputs != before.outputs {
                m |= Item::Outputs.mask();
            }
        }
        _ => {}
    }
    if now.online() != before.online() {
        m |= Item::Online.mask();
    }
    m
}

/// Whether a counter or a rotary moved from `before` to `now`.
fn moved(now: &DeviceView, before: &DeviceView) -> bool {
    match (now, before) {
        (DeviceView::C29u(a), DeviceView::C29u(b)) => a.counters != b.counters,
        (DeviceView::Trc(a), DeviceView::Trc(b)) => a.rotaries != b.rotaries,
        _ => true,
    }
}

/// The values `compared` holds for each counter and rotary of device `idx` that one tick's
/// change from `before` to `now` stepped over without landing on (a change of more than one
/// across it: two strokes between scans), into `stepped`. A change the long way round (a
/// counter or rotary wrapping) crosses nothing the script compares with.
fn note_steps(
    stepped: &mut BTreeMap<(usize, Item), BTreeSet<i64>>,
    compared: &BTreeMap<Item, BTreeSet<i64>>,
    idx: usize,
    (before, now): (&DeviceView, &DeviceView),
) {
    let mut step = |item: Item, (a, b): (i64, i64), wrap: i64| {
        let Some(values) = compared.get(&item) else {
            return;
        };
        if (b - a).abs() < 2 || (b - a).abs() > wrap / 2 {
            return;
        }
        let (lo, hi) = (a.min(b), a.max(b));
        for v in values.range(lo + 1..hi) {
            stepped.entry((idx, item)).or_default().insert(*v);
        }
    };
    match (before, now) {
        (DeviceView::C29u(a), DeviceView::C29u(b)) => {
            if let (Some(a), Some(b)) = (a.counters, b.counters) {
                for ch in 0..8u8 {
                    let (x, y) = (a[usize::from(ch)], b[usize::from(ch)]);
                    step(Item::Counter(ch), (x.into(), y.into()), 1 << 16);
                }
            }
        }
        (DeviceView::Trc(a), DeviceView::Trc(b)) => {
            if let (Some(a), Some(b)) = (a.rotaries, b.rotaries) {
                for r in Rotary::ALL {
                    step(Item::Rotary(r), (a.get(r).into(), b.get(r).into()), 1 << 8);
                }
            }
        }
        _ => {}
    }
}

/// Takes `value` into the range of `key`.
fn widen(ranges: &mut BTreeMap<(usize, Item), (i64, i64)>, key: (usize, Item), value: i64) {
    let r = ranges.entry(key).or_insert((value, value));
    r.0 = r.0.min(value);
    r.1 = r.1.max(value);
}

/// Takes the counters and rotaries device `idx` shows into their ranges.
fn note_ranges(ranges: &mut BTreeMap<(usize, Item), (i64, i64)>, idx: usize, shown: &DeviceView) {
    match shown {
        DeviceView::C29u(ModuleView {
            counters: Some(counters),
            ..
        }) => {
            for (ch, n) in (0u8..).zip(*counters) {
                widen(ranges, (idx, Item::Counter(ch)), i64::from(n));
            }
        }
        DeviceView::Trc(PanelView {
            rotaries: Some(rotaries),
            ..
        }) => {
            for r in Rotary::ALL {
                widen(ranges, (idx, Item::Rotary(r)), i64::from(rotaries.get(r)));
            }
        }
        _ => {}
    }
}

/// A counter or rotary the script reads: the range its ticks read, and the values it is
/// compared with that the range does not reach.
struct Reach {
    name: String,
    range: Option<(i64, i64)>,
    compared: Vec<i64>,
    missed: Vec<i64>,
    /// The values compared with that one tick's change stepped over.
    stepped: Vec<i64>,
}

/// What one run exercised (and, summed, what all runs did).
#[derive(Debug, Clone, Default)]
pub struct Coverage {
    /// Runs summed in.
    pub runs: u64,
    /// Ticks in all.
    pub ticks: u64,
    /// Device names by index.
    pub devices: Vec<String>,
    /// Handler label → times it ran.
    pub fired: BTreeMap<String, u64>,
    /// Handlers the script had at some point, fired or not.
    pub handlers: BTreeSet<String>,
    /// What the top level and the handlers read.
    pub script_reads: ReadSet,
    /// Invariant name → what it read.
    pub invariant_reads: BTreeMap<String, ReadSet>,
    /// Invariant name → ticks in which a value it reads changed.
    pub invariant_changes: BTreeMap<String, u64>,
    /// (device, item) → ticks in which it changed.
    pub changes: BTreeMap<(usize, Item), u64>,
    /// (device, counter or rotary) → the lowest and highest value a tick read.
    pub ranges: BTreeMap<(usize, Item), (i64, i64)>,
    /// Counter or rotary → the values the script compares it with (from its text).
    pub compared: BTreeMap<Item, BTreeSet<i64>>,
    /// (device, counter or rotary) → the values compared with that one tick's change stepped
    /// over by more than one (reaching a value is not crossing it).
    pub stepped_over: BTreeMap<(usize, Item), BTreeSet<i64>>,
    last: Vec<DeviceView>,
}

impl Coverage {
    /// Starts following a rig whose script compares counters and rotaries with `compared`.
    pub fn start(rig: &Rig, compared: &BTreeMap<Item, BTreeSet<i64>>) -> Self {
        let rt = rig.runner.runtime().borrow();
        let last: Vec<DeviceView> = rt.devices().iter().map(DeviceView::of).collect();
        let mut ranges = BTreeMap::new();
        for (idx, shown) in last.iter().enumerate() {
            note_ranges(&mut ranges, idx, shown);
        }
        Self {
            runs: 1,
            devices: rt.devices().iter().map(|d| d.name().to_string()).collect(),
            last,
            ranges,
            compared: compared.clone(),
            ..Self::default()
        }
    }

    /// Notes what changed in the tick that just ran.
    pub fn after_tick(&mut self, rig: &Rig) {
        self.ticks = self.ticks.saturating_add(1);
        let rt = rig.runner.runtime().borrow();
        let invariants = rig.runner.program().coverage();
        for (idx, d) in rt.devices().iter().enumerate() {
            let now = DeviceView::of(d);
            let Some(before) = self.last.get_mut(idx) else {
                continue;
            };
            // Ranges only when a value moved: a lookup per counter and rotary every tick would
            // cost a tenth of the search.
            let moved = moved(&now, before);
            let changed = changed(&now, before);
            if moved {
                note_steps(&mut self.stepped_over, &self.compared, idx, (before, &now));
            }
            *before = now;
            if moved {
                note_ranges(&mut self.ranges, idx, &now);
            }
            if changed == 0 {
                continue;
            }
            let mut rest = changed;
            while rest != 0 {
                let bit = rest.trailing_zeros();
                rest &= rest - 1;
                if let Some(item) = Item::from_bit(bit) {
                    *self.changes.entry((idx, item)).or_default() += 1;
                }
            }
            if let Some(c) = invariants {
                for (name, reads) in &c.invariant_reads {
                    if reads.mask(idx) & changed != 0 {
                        *self.invariant_changes.entry(name.clone()).or_default() += 1;
                    }
                }
            }
        }
    }

    /// Takes in what the program counted and the handlers it has, at the end of the run.
    pub fn finish(&mut self, rig: &Rig) {
        let rt = rig.runner.runtime().borrow();
        for s in rt.handlers().list() {
            self.handlers.insert(s.label.to_string());
        }
        if let Some(c) = rig.runner.program().coverage() {
            for (label, n) in &c.fired {
                *self.fired.entry(label.clone()).or_default() += n;
                self.handlers.insert(label.clone());
            }
            self.script_reads.union(&c.script_reads);
            for (name, reads) in &c.invariant_reads {
                self.invariant_reads
                    .entry(name.clone())
                    .or_default()
                    .union(reads);
            }
        }
        for inv in rt.invariants() {
            self.invariant_reads.entry(inv.name.clone()).or_default();
        }
    }

    /// Adds another run's coverage.
    pub fn merge(&mut self, other: &Coverage) {
        self.runs += other.runs;
        self.ticks += other.ticks;
        if self.devices.is_empty() {
            self.devices.clone_from(&other.devices);
        }
        for (k, v) in &other.fired {
            *self.fired.entry(k.clone()).or_default() += v;
        }
        self.handlers.extend(other.handlers.iter().cloned());
        self.script_reads.union(&other.script_reads);
        for (k, v) in &other.invariant_reads {
            self.invariant_reads.entry(k.clone()).or_default().union(v);
        }
        for (k, v) in &other.invariant_changes {
            *self.invariant_changes.entry(k.clone()).or_default() += v;
        }
        for (k, v) in &other.changes {
            *self.changes.entry(*k).or_default() += v;
        }
        for (k, (lo, hi)) in &other.ranges {
            widen(&mut self.ranges, *k, *lo);
            widen(&mut self.ranges, *k, *hi);
        }
        for (k, v) in &other.compared {
            self.compared
                .entry(*k)
                .or_default()
                .extend(v.iter().copied());
        }
        for (k, v) in &other.stepped_over {
            self.stepped_over
                .entry(*k)
                .or_default()
                .extend(v.iter().copied());
        }
    }

    fn item_name(&self, dev: usize, item: Item) -> String {
        let d = self.devices.get(dev).map_or("?", String::as_str);
        format!("{d} {item}")
    }

    /// Everything the script reads (handlers, top level, invariants), but what it set
    /// itself (its outputs).
    pub fn all_reads(&self) -> ReadSet {
        let mut all = self.script_reads.clone();
        for r in self.invariant_reads.values() {
            all.union(r);
        }
        all
    }

    /// Inputs the script reads that never changed in any run.
    pub fn unchanged_inputs(&self) -> Vec<String> {
        self.all_reads()
            .items()
            .into_iter()
            .filter(|(_, item)| !matches!(item, Item::Outputs | Item::Relay))
            .filter(|(dev, item)| !self.changes.contains_key(&(*dev, *item)))
            .map(|(dev, item)| self.item_name(dev, item))
            .collect()
    }

    /// Each counter and rotary the script reads, with its range and the values it is
    /// compared with.
    fn reaches(&self) -> Vec<Reach> {
        self.all_reads()
            .items()
            .into_iter()
            .filter(|(_, item)| matches!(item, Item::Counter(_) | Item::Rotary(_)))
            .map(|(dev, item)| {
                let range = self.ranges.get(&(dev, item)).copied();
                let compared: Vec<i64> = self
                    .compared
                    .get(&item)
                    .map(|s| s.iter().copied().collect())
                    .unwrap_or_default();
                let missed = compared
                    .iter()
                    .copied()
                    .filter(|v| !range.is_some_and(|(lo, hi)| (lo..=hi).contains(v)))
                    .collect();
                let stepped = self
                    .stepped_over
                    .get(&(dev, item))
                    .map(|s| s.iter().copied().collect())
                    .unwrap_or_default();
                Reach {
                    name: self.item_name(dev, item),
                    range,
                    compared,
                    missed,
                    stepped,
                }
            })
            .collect()
    }

    /// The warnings: handlers that never fired, invariants whose values never changed, values
    /// compared with that a counter or rotary never reached.
    pub fn warnings(&self) -> Vec<String> {
        let mut out = Vec::new();
        for h in &self.handlers {
            if h != "on_stop" && !self.fired.contains_key(h) {
                out.push(format!("handler {h} never fired"));
            }
        }
        for name in self.invariant_reads.keys() {
            if self.invariant_changes.get(name).copied().unwrap_or(0) == 0 {
                out.push(format!(
                    "invariant {name:?}: the values it reads never changed, so it was never \
                     put to the test"
                ));
            }
        }
        for r in self.reaches() {
            if !r.missed.is_empty() {
                out.push(format!(
                    "{} never reached {}, which the script compares it with ({})",
                    r.name,
                    words(&r.missed),
                    match r.range {
                        Some((lo, hi)) => format!("the runs read {lo}-{hi}"),
                        None => "never read".into(),
                    }
                ));
            }
        }
        out
    }

    /// The report in lines for people.
    pub fn lines(&self) -> Vec<String> {
        let mut out = vec![format!(
            "coverage over {} run(s), {} ticks:",
            self.runs, self.ticks
        )];
        for h in &self.handlers {
            let n = self.fired.get(h).copied().unwrap_or(0);
            out.push(format!("  handler {h}: fired {n} times"));
        }
        for (name, reads) in &self.invariant_reads {
            let n = self.invariant_changes.get(name).copied().unwrap_or(0);
            let what: Vec<String> = reads
                .items()
                .into_iter()
                .map(|(d, i)| self.item_name(d, i))
                .collect();
            out.push(format!(
                "  invariant {name:?}: the values it reads changed in {n} ticks ({})",
                if what.is_empty() {
                    "it reads nothing from the devices".to_string()
                } else {
                    what.join(", ")
                }
            ));
        }
        for r in self.reaches() {
            let range = r
                .range
                .map_or_else(|| "never read".into(), |(lo, hi)| format!("read {lo}-{hi}"));
            let compared = if r.compared.is_empty() {
                String::new()
            } else if r.missed.is_empty() {
                format!(", compared with {}: all reached", words(&r.compared))
            } else {
                format!(
                    ", compared with {}: {} not reached",
                    words(&r.compared),
                    words(&r.missed)
                )
            };
            let stepped = match (r.compared.is_empty(), r.stepped.is_empty()) {
                (true, _) => String::new(),
                (false, true) => "; none stepped over in one scan".into(),
                (false, false) => format!("; stepped over in one scan: {}", words(&r.stepped)),
            };
            out.push(format!("  {}: {range}{compared}{stepped}", r.name));
        }
        let unchanged = self.unchanged_inputs();
        if !unchanged.is_empty() {
            out.push(format!(
                "  read but never changed: {}",
                unchanged.join(", ")
            ));
        }
        out
    }

    /// The report as JSON.
    pub fn to_json(&self) -> Value {
        let invariants: serde_json::Map<String, Value> = self
            .invariant_reads
            .iter()
            .map(|(name, reads)| {
                let what: Vec<String> = reads
                    .items()
                    .into_iter()
                    .map(|(d, i)| self.item_name(d, i))
                    .collect();
                (
                    name.clone(),
                    json!({
                        "reads": what,
                        "changed_ticks": self.invariant_changes.get(name).copied().unwrap_or(0),
                    }),
                )
            })
            .collect();
        let handlers: serde_json::Map<String, Value> = self
            .handlers
            .iter()
            .map(|h| (h.clone(), json!(self.fired.get(h).copied().unwrap_or(0))))
            .collect();
        let ranges: serde_json::Map<String, Value> = self
            .reaches()
            .into_iter()
            .map(|r| {
                (
                    r.name,
                    json!({
                        "min": r.range.map(|x| x.0),
                        "max": r.range.map(|x| x.1),
                        "compared": r.compared,
                        "not_reached": r.missed,
                        "stepped_over": r.stepped,
                    }),
                )
            })
            .collect();
        json!({
            "runs": self.runs,
            "ticks": self.ticks,
            "handlers": handlers,
            "ranges": ranges,
            "invariants": invariants,
            "unchanged_inputs": self.unchanged_inputs(),
            "warnings": self.warnings(),
        })
    }
}

/// `300`, `12 and 300`, `1, 12 and 300`.
fn words(values: &[i64]) -> String {
    let texts: Vec<String> = values.iter().map(ToString::to_string).collect();
    match texts.split_last() {
        Some((last, [])) => last.clone(),
        Some((last, rest)) => format!("{} and {last}", rest.join(", ")),
        None => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_value_stepped_over_in_one_tick_is_told_apart_from_one_reached() {
        let compared = BTreeMap::from([(Item::Counter(2), BTreeSet::from([20, 300]))]);
        let module = |n: u16| {
            let mut counters = [0; 8];
            counters[2] = n;
            DeviceView::C29u(ModuleView {
                online: true,
                inputs: Some(0),
                outputs: 0,
                counters: Some(counters),
                latches: None,
            })
        };
        let mut stepped = BTreeMap::new();
        // 19 -> 20 -> 21 lands on 20; 299 -> 301 steps over 300; a wrap crosses nothing.
        for (a, b) in [(19, 20), (20, 21), (299, 301), (65_530, 3)] {
            note_steps(&mut stepped, &compared, 0, (&module(a), &module(b)));
        }
        assert_eq!(
            stepped,
            BTreeMap::from([((0, Item::Counter(2)), BTreeSet::from([300]))])
        );
        let mut c = Coverage {
            devices: vec!["io".into()],
            compared: compared.clone(),
            stepped_over: stepped,
            ..Coverage::default()
        };
        c.script_reads.add(0, Item::Counter(2));
        widen(&mut c.ranges, (0, Item::Counter(2)), 0);
        widen(&mut c.ranges, (0, Item::Counter(2)), 400);
        let lines = c.lines();
        assert!(
            lines.contains(
                &"  io counter DI2: read 0-400, compared with 20 and 300: all reached; stepped \
                  over in one scan: 300"
                    .into()
            ),
            "{lines:#?}"
        );
    }

    #[test]
    fn counters_and_rotaries_report_their_range_against_the_values_compared_with() {
        let mut c = Coverage {
            devices: vec!["io".into(), "panel".into()],
            ..Coverage::default()
        };
        c.script_reads.add(0, Item::Counter(0));
        c.script_reads.add(1, Item::Rotary(Rotary::S41A));
        c.compared
            .insert(Item::Counter(0), BTreeSet::from([12, 300]));
        c.compared
            .insert(Item::Rotary(Rotary::S41A), BTreeSet::from([4]));
        widen(&mut c.ranges, (0, Item::Counter(0)), 0);
        widen(&mut c.ranges, (0, Item::Counter(0)), 45);
        widen(&mut c.ranges, (1, Item::Rotary(Rotary::S41A)), 250);
        widen(&mut c.ranges, (1, Item::Rotary(Rotary::S41A)), 3);
        let lines = c.lines();
        assert!(
            lines.contains(
                &"  io counter DI0: read 0-45, compared with 12 and 300: 300 not reached; none \
                  stepped over in one scan"
                    .into()
            ),
            "{lines:#?}"
        );
        assert!(
            lines.contains(
                &"  panel S41A: read 3-250, compared with 4: all reached; none stepped over in \
                  one scan"
                    .into()
            ),
            "{lines:#?}"
        );
        assert_eq!(
            c.warnings(),
            vec![
                "io counter DI0 never reached 300, which the script compares it with (the runs \
                 read 0-45)"
                    .to_string()
            ]
        );
        let mut other = Coverage::default();
        widen(&mut other.ranges, (0, Item::Counter(0)), 301);
        c.merge(&other);
        assert!(c.warnings().is_empty(), "{:?}", c.warnings());
    }
}
