//! What the script's text says that the search must reach, read from its syntax tree before any
//! run: the durations of its `every` and `after` timers, its cron expressions, and the values it
//! compares counters and rotaries with (`io.counter(0) >= BATCH`, `panel.rotary("S41A") == 12`,
//! `on_counter(0, 300, ..)`). Literals and the script's `const`/`let` names bound to literals
//! count; a variable bound to a counter read (`let n = io.counter(0);`) stands for the counter.

use crate::protocol::trc1000::Rotary;
use crate::script::engine::{sandboxed, DEFAULT_BUDGET};
use crate::script::reads::Item;
use crate::time::duration::{duration_from_millis_i64, parse_duration};
use rhai::{ASTNode, Expr, Stmt, AST};
use std::collections::{BTreeMap, BTreeSet};
use std::time::Duration;

/// Values kept per counter or rotary (the first found): a script compares with a few.
pub const MAX_VALUES: usize = 16;

/// The comparison operators whose constant side is a value worth reaching.
const COMPARISONS: [&str; 6] = ["==", "!=", "<", "<=", ">", ">="];

/// What the script's text says.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Facts {
    /// `every` and `after` durations written as literals or constants.
    pub timers: BTreeSet<Duration>,
    /// Cron expressions written as literals or constants.
    pub crons: BTreeSet<String>,
    /// Counter or rotary → the values the script compares it with (counters 0-65535,
    /// rotaries 0-255).
    pub compared: BTreeMap<Item, BTreeSet<i64>>,
}

/// A device input an expression reads: a counter (`None`: the channel is not known) or a
/// rotary.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Read {
    Counter(Option<u8>),
    Rotary(Rotary),
}

/// Names the script binds, by what they are bound to (every binding of a name counts).
#[derive(Default)]
struct Names {
    ints: BTreeMap<String, BTreeSet<i64>>,
    strings: BTreeMap<String, BTreeSet<String>>,
    reads: BTreeMap<String, BTreeSet<Read>>,
}

fn name_of(e: &Expr) -> Option<&str> {
    match e {
        Expr::Variable(x, ..) => Some(x.1.as_str()),
        _ => None,
    }
}

impl Names {
    /// The integers `e` may stand for.
    fn ints(&self, e: &Expr) -> BTreeSet<i64> {
        match e {
            Expr::IntegerConstant(i, _) => BTreeSet::from([*i]),
            Expr::DynamicConstant(d, _) => {
                d.as_int().map(|i| BTreeSet::from([i])).unwrap_or_default()
            }
            Expr::Variable(..) => name_of(e)
                .and_then(|n| self.ints.get(n))
                .cloned()
                .unwrap_or_default(),
            Expr::FnCall(call, _) => match (call.name.as_str(), call.args.as_slice()) {
                ("-", [a]) => self.ints(a).into_iter().map(i64::wrapping_neg).collect(),
                (op @ ("+" | "-" | "*"), [a, b]) => {
                    let (a, b) = (self.ints(a), self.ints(b));
                    let mut out = BTreeSet::new();
                    for x in &a {
                        for y in &b {
                            out.insert(match op {
                                "+" => x.wrapping_add(*y),
                                "-" => x.wrapping_sub(*y),
                                _ => x.wrapping_mul(*y),
                            });
                        }
                    }
                    out
                }
                _ => BTreeSet::new(),
            },
            _ => BTreeSet::new(),
        }
    }

    /// The strings `e` may stand for.
    fn strings(&self, e: &Expr) -> BTreeSet<String> {
        match e {
            Expr::StringConstant(s, _) => BTreeSet::from([s.to_string()]),
            Expr::Variable(..) => name_of(e)
                .and_then(|n| self.strings.get(n))
                .cloned()
                .unwrap_or_default(),
            _ => BTreeSet::new(),
        }
    }

    /// The durations `e` may stand for (a string, or a number of milliseconds).
    fn durations(&self, e: &Expr) -> BTreeSet<Duration> {
        let from_text = self
            .strings(e)
            .into_iter()
            .filter_map(|s| parse_duration(&s).ok());
        let from_ms = self
            .ints(e)
            .into_iter()
            .filter_map(|ms| duration_from_millis_i64(ms).ok());
        from_text.chain(from_ms).collect()
    }

    /// The counters and rotaries `e` reads, anywhere inside it (`io.counter(0) - start`).
    fn reads(&self, e: &Expr) -> BTreeSet<Read> {
        let mut out = BTreeSet::new();
        self.reads_into(e, &mut out, 0);
        out
    }

    fn reads_into(&self, e: &Expr, out: &mut BTreeSet<Read>, depth: usize) {
        if depth > 16 {
            return;
        }
        match e {
            Expr::Variable(..) => {
                if let Some(r) = name_of(e).and_then(|n| self.reads.get(n)) {
                    out.extend(r.iter().copied());
                }
            }
            Expr::MethodCall(call, _) => match (call.name.as_str(), call.args.first()) {
                ("counter", Some(ch)) => {
                    let chs = self.ints(ch);
                    if chs.is_empty() {
                        out.insert(Read::Counter(None));
                    }
                    for c in chs {
                        out.insert(Read::Counter(u8::try_from(c).ok().filter(|c| *c < 8)));
                    }
                }
                ("rotary", Some(name)) => {
                    out.extend(
                        self.strings(name)
                            .iter()
                            .filter_map(|n| Rotary::from_name(n))
                            .map(Read::Rotary),
                    );
                }
                _ => {}
            },
            Expr::Dot(x, ..) => self.reads_into(&x.rhs, out, depth + 1),
            Expr::Index(x, ..) => {
                // `io.counters()[ch]`
                if let Expr::Dot(d, ..) = &x.lhs {
                    if matches!(&d.rhs, Expr::MethodCall(c, _) if c.name.as_str() == "counters") {
                        let chs = self.ints(&x.rhs);
                        if chs.is_empty() {
                            out.insert(Read::Counter(None));
                        }
                        for c in chs {
                            out.insert(Read::Counter(u8::try_from(c).ok().filter(|c| *c < 8)));
                        }
                    }
                }
                self.reads_into(&x.lhs, out, depth + 1);
            }
            Expr::FnCall(call, _) => {
                for a in &call.args {
                    self.reads_into(a, out, depth + 1);
                }
            }
            _ => {}
        }
    }
}

impl Facts {
    /// Reads `source`; a script that does not compile says nothing (the run will say why).
    pub fn read(source: &str) -> Self {
        match sandboxed(DEFAULT_BUDGET).compile(source) {
            Ok(ast) => Self::of(&ast),
            Err(_) => Self::default(),
        }
    }

    /// Reads a compiled script.
    pub fn of(ast: &AST) -> Self {
        let mut names = Names::default();
        ast.walk(&mut |path: &[ASTNode]| {
            if let Some(ASTNode::Stmt(Stmt::Var(x, ..))) = path.last() {
                let (name, value) = (x.0.name.to_string(), &x.1);
                let ints = names.ints(value);
                if !ints.is_empty() {
                    names.ints.entry(name.clone()).or_default().extend(ints);
                }
                if let Expr::StringConstant(s, _) = value {
                    names
                        .strings
                        .entry(name.clone())
                        .or_default()
                        .insert(s.to_string());
                }
                let reads = names.reads(value);
                if !reads.is_empty() {
                    names.reads.entry(name).or_default().extend(reads);
                }
            }
            true
        });
        let mut facts = Facts::default();
        ast.walk(&mut |path: &[ASTNode]| {
            let call = match path.last() {
                Some(ASTNode::Expr(Expr::FnCall(call, _) | Expr::MethodCall(call, _))) => call,
                Some(ASTNode::Stmt(Stmt::FnCall(call, _))) => call,
                _ => return true,
            };
            let name = call.name.as_str();
            match (name, call.args.as_slice()) {
                ("every" | "after", [d, ..]) => facts.timers.extend(names.durations(d)),
                ("cron", [e, ..]) => facts.crons.extend(names.strings(e)),
                ("on_counter", [ch, threshold, ..]) => {
                    let chs = names.ints(ch);
                    for t in names.ints(threshold) {
                        for c in &chs {
                            if let Ok(c) = u8::try_from(*c) {
                                facts.note(Read::Counter(Some(c)), t);
                            }
                        }
                    }
                }
                (op, [a, b]) if COMPARISONS.contains(&op) => {
                    for (subject, value) in [(a, b), (b, a)] {
                        for read in names.reads(subject) {
                            for v in names.ints(value) {
                                facts.note(read, v);
                            }
                        }
                    }
                }
                _ => {}
            }
            true
        });
        facts.timers.retain(|d| !d.is_zero());
        facts
    }

    /// Notes that `read` is compared with `value` (out of its range: dropped).
    fn note(&mut self, read: Read, value: i64) {
        let (items, max): (Vec<Item>, i64) = match read {
            Read::Counter(Some(ch)) if ch < 8 => (vec![Item::Counter(ch)], 65535),
            Read::Counter(_) => ((0..8).map(Item::Counter).collect(), 65535),
            Read::Rotary(r) => (vec![Item::Rotary(r)], 255),
        };
        if !(0..=max).contains(&value) {
            return;
        }
        for item in items {
            let set = self.compared.entry(item).or_default();
            if set.len() < MAX_VALUES {
                set.insert(value);
            }
        }
    }

    /// The values the script compares counter `ch` with.
    pub fn counter_values(&self, ch: u8) -> Vec<u16> {
        self.compared
            .get(&Item::Counter(ch))
            .map(|s| s.iter().filter_map(|v| u16::try_from(*v).ok()).collect())
            .unwrap_or_default()
    }

    /// The values the script compares rotary `r` with.
    pub fn rotary_values(&self, r: Rotary) -> Vec<u8> {
        self.compared
            .get(&Item::Rotary(r))
            .map(|s| s.iter().filter_map(|v| u8::try_from(*v).ok()).collect())
            .unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counter_comparisons_with_literals_and_constants_are_found() {
        let f = Facts::read(
            r#"
const PARTS = 2;
const LIMIT = 300;
let io = device("io");
io.on_counter(PARTS, 100, |n| {});
every("20ms", || {
    if io.counter(PARTS) >= LIMIT { io.outputs = 0; }
    let n = io.counter(5);
    if n == 40 || 12 > n { }
    if io.counter(1) - 3 < LIMIT - 1 { }
    if io.counters()[4] != 70000 { }
});
"#,
        );
        assert_eq!(f.counter_values(2), vec![100, 300]);
        assert_eq!(f.counter_values(5), vec![12, 40]);
        assert_eq!(f.counter_values(1), vec![299]);
        assert!(
            f.counter_values(4).is_empty(),
            "70000 is past what a counter holds"
        );
        assert!(f.counter_values(0).is_empty());
        assert_eq!(f.timers, BTreeSet::from([Duration::from_millis(20)]));
    }

    #[test]
    fn timers_crons_and_rotary_comparisons_are_found_through_constants() {
        let f = Facts::read(
            r#"
const LONG = "75s";
const SCHEDULE = "0 */5 * * * *";
const KNOB = "S41A";
let panel = device("panel");
panel.on_press("S3", || after(LONG, || {}));
after(1500, || {});
cron(SCHEDULE, || {});
fn far(panel) { panel.rotary(KNOB) > 9 }
every("1s", || if panel.rotary("S42B") == 200 {});
"#,
        );
        assert_eq!(
            f.timers,
            BTreeSet::from([
                Duration::from_millis(1500),
                Duration::from_secs(1),
                Duration::from_secs(75)
            ])
        );
        assert_eq!(f.crons, BTreeSet::from(["0 */5 * * * *".to_string()]));
        assert_eq!(f.rotary_values(Rotary::S41A), vec![9]);
        assert_eq!(f.rotary_values(Rotary::S42B), vec![200]);
    }

    #[test]
    fn a_script_that_does_not_compile_says_nothing() {
        assert_eq!(Facts::read("let x = ;"), Facts::default());
    }
}
