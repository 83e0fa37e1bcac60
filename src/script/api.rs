//! The script API: `device(name)` and its TRC1000 and TRP-C29U handles, timers and flow
//! (`every`, `after`, `cron`, `cancel`, `on_stop`, `stop`, `now`, `uptime`), invariants
//! (`invariant`), records (`record`, `measure`) and messages (`print`, `log`, `warn`), bound to
//! the runtime.
//!
//! Inputs read through a handle come from the tick's snapshot (the first access in a tick
//! reads the device); outputs set through it are written once at the end of the tick. Other
//! operations (`clear_counter`, `save_counters`, `watchdog`, `safe_value = ..`, `reset`, ...)
//! are done at once. A bad device name, switch name or channel is a script error at the
//! call's line and column.

use super::engine::Guard;
use super::error::STOP_MARKER;
use super::point_names::{channel_named, rotary_named, switch_named, Way};
use super::reads::{Item, ReadTracker, ALL_COUNTERS, ALL_INPUTS, ALL_SWITCHES};
use super::values::to_json;
use crate::config::PointNames;
use crate::device::c29u::{C29uError, WatchdogTimeout};
use crate::protocol::trc1000::{Rotary, Switch};
use crate::runtime::devices::DeviceError;
use crate::runtime::handlers::Source;
use crate::runtime::records::Limits;
use crate::runtime::script_context::{DeviceKind, ScriptContext};
use crate::time::duration::{duration_from_millis_f64, duration_from_millis_i64, parse_duration};
use rhai::{Array, Dynamic, Engine, EvalAltResult, FnPtr, Map, NativeCallContext, Position, AST};
use std::cell::RefCell;
use std::collections::HashMap;
use std::rc::Rc;
use std::time::Duration;

/// The run as the bindings hold it: requests, never its state.
pub type Rt = ScriptContext<Handler>;

/// A script function the runtime calls (a handler, a timer's, an invariant's): shared, so a
/// tick's call of it copies no captured values.
pub type Handler = Rc<FnPtr>;

/// What a binding returns.
pub type R<T> = Result<T, Box<EvalAltResult>>;

/// A script error with `message` (Rhai adds the call's position).
pub fn fail<T>(message: impl Into<String>) -> R<T> {
    Err(message.into().into())
}

/// Handler-taking calls: (name, index of the handler argument, the parameters it gets); the
/// bindings (`Arities::check`) and `check` both read it.
pub(super) const HANDLERS: &[(&str, usize, &[&str])] = &[
    ("on_press", 1, &["switch name"]),
    ("on_release", 1, &["switch name"]),
    ("on_turn", 1, &["delta", "value"]),
    ("on_rise", 1, &["channel"]),
    ("on_fall", 1, &["channel"]),
    ("on_counter", 2, &["count"]),
    ("every", 1, &["missed"]),
    ("cron", 1, &["missed"]),
    ("after", 1, &[]),
    ("on_stop", 0, &[]),
    ("on_reload", 0, &[]),
    ("invariant", 1, &[]),
    ("on_command", 1, &["payload"]),
    ("on_message", 1, &["topic", "payload"]),
];

/// How many parameters each function of the script takes, by name (filled after compiling,
/// so handlers get only the arguments they take, and too many parameters are an error).
#[derive(Clone, Default)]
pub struct Arities(Rc<RefCell<HashMap<String, Vec<usize>>>>);

impl Arities {
    /// Learns the functions of `ast`.
    pub fn learn(&self, ast: &AST) {
        let mut map = self.0.borrow_mut();
        map.clear();
        for f in ast.iter_functions() {
            map.entry(f.name.to_string())
                .or_default()
                .push(f.params.len());
        }
    }

    /// The parameter counts `f` can be called with (its curried captures taken off), if
    /// it is a function of the script.
    pub fn of(&self, f: &FnPtr) -> Option<Vec<usize>> {
        self.counts(f, |counts| counts.collect())
    }

    /// How many of `offered` arguments to pass to `f`: the most it takes, up to `offered`.
    pub fn pick(&self, f: &FnPtr, offered: usize) -> usize {
        self.counts(f, |counts| counts.filter(|n| *n <= offered).max())
            .flatten()
            .unwrap_or(offered)
    }

    /// `use_them` on `of(f)`'s counts, without collecting them (`pick` runs for every
    /// handler call).
    fn counts<T>(
        &self,
        f: &FnPtr,
        use_them: impl FnOnce(&mut dyn Iterator<Item = usize>) -> T,
    ) -> Option<T> {
        let curried = f.curry().len();
        let arities = self.0.borrow();
        let counts = arities.get(f.fn_name())?;
        Some(use_them(
            &mut counts.iter().filter_map(|n| n.checked_sub(curried)),
        ))
    }

    /// An error if `f` cannot be a handler for `what` (named in `HANDLERS`, with the
    /// parameters it passes).
    pub fn check(&self, f: &FnPtr, what: &str) -> R<()> {
        let params = HANDLERS
            .iter()
            .find(|(name, ..)| *name == what)
            .map_or(&[][..], |(.., params)| *params);
        let Some(counts) = self.of(f) else {
            return Ok(());
        };
        if counts.is_empty() || counts.iter().any(|n| *n <= params.len()) {
            return Ok(());
        }
        let takes = counts.iter().min().copied().unwrap_or(0);
        fail(format!(
            "the handler of {what} {}; this function takes {takes}",
            takes_words(params)
        ))
    }
}

/// "takes no parameters" / "takes at most 1 parameter (name)".
pub fn takes_words(params: &[&str]) -> String {
    match params {
        [] => "takes no parameters".into(),
        [one] => format!("takes at most 1 parameter ({one})"),
        many => format!(
            "takes at most {} parameters ({})",
            many.len(),
            many.join(", ")
        ),
    }
}

/// A TRC1000 in a script.
#[derive(Clone)]
pub struct Panel {
    rt: Rt,
    idx: usize,
    name: Rc<str>,
    names: Rc<PointNames>,
    reads: ReadTracker,
}

/// A TRP-C29U in a script.
#[derive(Clone)]
pub struct Io {
    rt: Rt,
    idx: usize,
    name: Rc<str>,
    names: Rc<PointNames>,
    reads: ReadTracker,
}

impl Panel {
    fn read(&self, mask: u128) {
        self.reads.note(self.idx, mask);
    }
}

impl Io {
    fn read(&self, mask: u128) {
        self.reads.note(self.idx, mask);
    }
}

/// A duration from a script value: `"20ms"`, `"1.5s"`, `"5m"`, or milliseconds.
pub fn duration(v: &Dynamic) -> R<Duration> {
    let r = if v.is_string() {
        parse_duration(&v.to_string())
    } else if let Some(i) = v.clone().try_cast::<i64>() {
        duration_from_millis_i64(i)
    } else if let Some(f) = v.clone().try_cast::<f64>() {
        duration_from_millis_f64(f)
    } else {
        return fail(format!(
            "{} is not a duration; use \"20ms\", \"1.5s\", \"5m\" or a number of milliseconds",
            v.type_name()
        ));
    };
    r.or_else(|e| fail(e.to_string()))
}

/// The channel `ch` of module `d`: a number 0-7, or a name rig.toml gives one of its
/// channels of `way` (`"guard door"`).
fn channel(d: &Io, ch: &Dynamic, way: Way) -> R<u8> {
    if let Ok(n) = ch.as_int() {
        return match u8::try_from(n) {
            Ok(c) if c < 8 => Ok(c),
            _ => fail(format!(
                "channel {n} does not exist on {} (TRP-C29U): use 0-7",
                d.name
            )),
        };
    }
    let Some(text) = ch.read_lock::<rhai::ImmutableString>() else {
        return fail(format!(
            "{} is not a channel: use 0-7 or a name rig.toml gives one",
            ch.type_name()
        ));
    };
    channel_named(&d.names, &format!("{} (TRP-C29U)", d.name), &text, way).or_else(fail)
}

fn byte(what: &str, v: i64) -> R<u8> {
    u8::try_from(v).or_else(|_| fail(not_a_byte(what, v)))
}

/// Why `v` cannot be a `what` ("DO byte"), in the words of the runtime and of `check`.
pub(super) fn not_a_byte(what: &str, v: i64) -> String {
    format!("{v} is not a {what}: use 0-255 (0x00-0xFF, 0b00000000-0b11111111)")
}

/// Why `v` is no relay position of the TRC1000 `dev`, in the words of the runtime and `check`.
pub(super) fn no_relay(dev: &str, v: i64) -> String {
    format!("relay {v} does not exist on {dev} (TRC1000): use 0-7")
}

/// The byte properties of a TRP-C29U with their names in messages (for `check`).
pub(super) const BYTE_PROPERTIES: &[(&str, &str)] = &[
    ("outputs", "DO byte"),
    ("safe_value", "safe value"),
    ("power_on_value", "power-on value"),
];

/// The switch `name` of panel `p`: `S12`, or a name rig.toml gives one.
fn switch(p: &Panel, name: &str) -> R<Switch> {
    switch_named(&p.names, &format!("{} (TRC1000)", p.name), name).or_else(fail)
}

/// The rotary `name` of panel `p`: `S41A`, or a name rig.toml gives one.
fn rotary(p: &Panel, name: &str) -> R<Rotary> {
    rotary_named(&p.names, &format!("{} (TRC1000)", p.name), name).or_else(fail)
}

/// A device operation's failure as a script error; one that a stop cut short ends the handler
/// at once, as `stop()` does (the run is ending, and that is no fault of the script's).
fn device_error<T>(dev: &str, e: &DeviceError) -> R<T> {
    if e.is_cancelled() {
        return end_handler();
    }
    let text = e.to_string();
    if text.starts_with(dev) {
        fail(text)
    } else {
        fail(format!("{dev}: {text}"))
    }
}

/// Runs a TRP-C29U operation at once, given the time now (refused while the device is lost).
fn c29u_op<T>(
    io: &Io,
    op: impl FnOnce(&mut crate::runtime::devices::C29uDevice, Duration) -> Result<T, DeviceError>,
) -> R<T> {
    let r = io.rt.on_module(io.idx, op);
    r.or_else(|e| device_error(&io.name, &e))
}

/// Registers the whole script API on `engine` over `rt` (with `resolve_variables` for a run),
/// noting what the script reads from its devices in `reads` (when that tracks) and placing
/// invariants in `file` (shared: a reload names another file), and what `watch(...)` chooses
/// in `watch`.
pub fn register(
    engine: &mut Engine,
    rt: &Rt,
    arities: &Arities,
    reads: &ReadTracker,
    file: &Rc<std::cell::RefCell<String>>,
    watch: &super::watched::Watch,
) {
    watch.register(engine);
    register_device(engine, rt, reads);
    register_panel(engine, arities);
    register_io(engine, arities);
    register_flow(engine, rt, arities);
    register_invariant(engine, rt, arities, file);
    register_records(engine, rt);
}

/// Registers a property setter as pure: a handle is a name for a device, and setting a
/// property changes the device, not the handle, so it may be done on a constant handle (such
/// as the copies `on_var` hands out, below).
fn setter<T: rhai::Variant + Clone>(
    engine: &mut Engine,
    property: &str,
    f: impl Fn(&mut T, i64) -> R<()> + 'static,
) {
    rhai::FuncRegistration::new(format!("set${property}"))
        .with_purity(true)
        .register_into_engine(engine, f);
}

/// The handle of the device at `idx`.
fn handle(rt: &Rt, idx: usize, reads: &ReadTracker) -> Option<Dynamic> {
    let (name, kind) = rt.device(idx)?;
    let names = rt.point_names(idx);
    let (rt, reads) = (rt.clone(), reads.clone());
    Some(match kind {
        DeviceKind::Trc1000 => Dynamic::from(Panel {
            rt,
            idx,
            name,
            names,
            reads,
        }),
        DeviceKind::C29u => Dynamic::from(Io {
            rt,
            idx,
            name,
            names,
            reads,
        }),
    })
}

fn register_device(engine: &mut Engine, rt: &Rt, reads: &ReadTracker) {
    let (r, t) = (rt.clone(), reads.clone());
    engine.register_fn("device", move |name: &str| -> R<Dynamic> {
        let idx = r.device_index(name);
        match idx.and_then(|i| handle(&r, i, &t)) {
            Some(h) => Ok(h),
            None => fail(format!(
                "no device called {name:?} in this rig (devices: {})",
                r.device_names()
            )),
        }
    });
}

/// Resolves the script's variables as a run needs them: each is checked by `guard` as it is
/// used (`engine::Guard::check_var`), and each device is a variable of its name (its reads
/// noted in `reads`).
pub fn resolve_variables(engine: &mut Engine, rt: &Rt, guard: &Rc<Guard>, reads: &ReadTracker) {
    // Each device is also a variable of its name. And a shared or constant variable holding a
    // device handle is read as a plain copy of it: a handler that uses the device it is
    // registered on (`io.on_rise(3, || io.outputs = 1)`) captures `io`, which Rhai shares and
    // locks while `io.on_rise` runs; the copy keeps Rhai's data-race check from refusing that
    // (and a constant's from refusing its methods). A plain one (a function's parameter) is
    // used in place: a copy is an allocation, and a tick reads handles many times.
    let (r, t) = (rt.clone(), reads.clone());
    let names: Vec<(String, usize)> = rt.names().into_iter().zip(0..).collect();
    let guard = Rc::clone(guard);
    // Rhai marks on_var "volatile" (it may change in a later release), not deprecated.
    #[allow(deprecated)]
    engine.on_var(move |name, _index, ctx| {
        let value = ctx.scope().get(name);
        guard.check_var(value, &ctx)?;
        match value {
            Some(v)
                if (v.is_shared() || v.is_read_only())
                    && !v.is_locked()
                    && (v.is::<Panel>() || v.is::<Io>()) =>
            {
                Ok(Some(v.flatten_clone()))
            }
            Some(_) => Ok(None),
            None => Ok(names
                .iter()
                .find(|(n, _)| n == name)
                .and_then(|(_, i)| handle(&r, *i, &t))),
        }
    });
}

fn register_panel(engine: &mut Engine, arities: &Arities) {
    engine.register_type_with_name::<Panel>("TRC1000");
    engine.register_fn("to_string", |p: &mut Panel| format!("TRC1000 {}", p.name));
    engine.register_fn("to_debug", |p: &mut Panel| format!("TRC1000 {}", p.name));
    engine.register_get("online", |p: &mut Panel| {
        p.read(Item::Online.mask());
        p.rt.online(p.idx)
    });
    engine.register_get("relay", |p: &mut Panel| {
        p.read(Item::Relay.mask());
        i64::from(p.rt.wanted_relay(p.idx))
    });
    setter(engine, "relay", |p: &mut Panel, v: i64| -> R<()> {
        match u8::try_from(v) {
            Ok(r) if r < 8 => {
                p.rt.set_relay(p.idx, r);
                Ok(())
            }
            _ => fail(no_relay(&p.name, v)),
        }
    });
    engine.register_fn("pressed", |p: &mut Panel, name: &str| -> R<bool> {
        let s = switch(p, name)?;
        p.read(Item::Switch(s).mask());
        Ok(p.rt.switches(p.idx).is_pressed(s))
    });
    engine.register_fn("pressed", |p: &mut Panel| -> Array {
        p.read(ALL_SWITCHES);
        let set = p.rt.switches(p.idx);
        set.pressed_names()
            .into_iter()
            .map(|n| Dynamic::from(n.to_string()))
            .collect()
    });
    engine.register_fn("rotary", |p: &mut Panel, name: &str| -> R<i64> {
        let r = rotary(p, name)?;
        p.read(Item::Rotary(r).mask());
        Ok(i64::from(p.rt.rotaries(p.idx).get(r)))
    });
    engine.register_fn("turned", |p: &mut Panel, name: &str| -> R<i64> {
        let r = rotary(p, name)?;
        p.read(Item::Rotary(r).mask());
        Ok(p.rt.turned(p.idx, r))
    });
    for (method, pressed) in [("on_press", true), ("on_release", false)] {
        let a = arities.clone();
        engine.register_fn(
            method,
            move |p: &mut Panel, name: &str, f: FnPtr| -> R<i64> {
                let s = switch(p, name)?;
                a.check(&f, method)?;
                p.read(Item::Switch(s).mask());
                let source = if pressed {
                    Source::Press {
                        dev: p.idx,
                        switch: s,
                    }
                } else {
                    Source::Release {
                        dev: p.idx,
                        switch: s,
                    }
                };
                let label = format!("{}.{method} {}", p.name, p.names.shown(s.name()));
                let id = p.rt.subscribe(source, Rc::new(f), label);
                Ok(id_value(id))
            },
        );
    }
    let a = arities.clone();
    engine.register_fn(
        "on_turn",
        move |p: &mut Panel, name: &str, f: FnPtr| -> R<i64> {
            let r = rotary(p, name)?;
            a.check(&f, "on_turn")?;
            p.read(Item::Rotary(r).mask());
            let label = format!("{}.on_turn {}", p.name, p.names.shown(r.name()));
            let source = Source::Turn {
                dev: p.idx,
                rotary: r,
            };
            Ok(id_value(p.rt.subscribe(source, Rc::new(f), label)))
        },
    );
}

fn id_value(id: u64) -> i64 {
    i64::try_from(id).unwrap_or(i64::MAX)
}

fn register_io(engine: &mut Engine, arities: &Arities) {
    engine.register_type_with_name::<Io>("TRP-C29U");
    engine.register_fn("to_string", |d: &mut Io| format!("TRP-C29U {}", d.name));
    engine.register_fn("to_debug", |d: &mut Io| format!("TRP-C29U {}", d.name));
    engine.register_get("online", |d: &mut Io| {
        d.read(Item::Online.mask());
        d.rt.online(d.idx)
    });
    engine.register_get("outputs", |d: &mut Io| {
        d.read(Item::Outputs.mask());
        i64::from(d.rt.wanted_outputs(d.idx))
    });
    setter(engine, "outputs", |d: &mut Io, v: i64| -> R<()> {
        let v = byte("DO byte", v)?;
        d.rt.set_outputs(d.idx, v);
        Ok(())
    });
    engine.register_fn("output", |d: &mut Io, ch: Dynamic| -> R<bool> {
        let c = channel(d, &ch, Way::Output)?;
        d.read(Item::Outputs.mask());
        Ok(d.rt.wanted_outputs(d.idx) & (1 << c) != 0)
    });
    engine.register_fn("set_output", |d: &mut Io, ch: Dynamic, on: bool| -> R<()> {
        let c = channel(d, &ch, Way::Output)?;
        d.rt.set_output(d.idx, c, on);
        Ok(())
    });
    engine.register_get("inputs", |d: &mut Io| {
        d.read(ALL_INPUTS);
        i64::from(d.rt.inputs(d.idx))
    });
    engine.register_fn("input", |d: &mut Io, ch: Dynamic| -> R<bool> {
        let c = channel(d, &ch, Way::Input)?;
        d.read(Item::Input(c).mask());
        Ok(d.rt.inputs(d.idx) & (1 << c) != 0)
    });
    engine.register_fn("counter", |d: &mut Io, ch: Dynamic| -> R<i64> {
        let c = channel(d, &ch, Way::Input)?;
        d.read(Item::Counter(c).mask());
        let counts = d.rt.counters(d.idx);
        Ok(counts.get(usize::from(c)).map_or(0, |v| i64::from(*v)))
    });
    engine.register_fn("counters", |d: &mut Io| -> Array {
        d.read(ALL_COUNTERS);
        let counts = d.rt.counters(d.idx);
        counts
            .iter()
            .map(|v| Dynamic::from(i64::from(*v)))
            .collect()
    });
    engine.register_fn("clear_counter", |d: &mut Io, ch: Dynamic| -> R<()> {
        let c = channel(d, &ch, Way::Input)?;
        c29u_op(d, |m, _| m.clear_counter(c))
    });
    engine.register_fn("clear_counters", |d: &mut Io| -> R<()> {
        c29u_op(d, |m, _| m.clear_counters())
    });
    engine.register_fn("save_counters", |d: &mut Io| -> R<()> {
        c29u_op(d, |m, _| Ok(m.driver().save_counters()?))
    });
    engine.register_fn("latched", |d: &mut Io| -> Map {
        d.read(Item::Latches.mask());
        let l = d.rt.latches(d.idx);
        // "on": channels energized since the last clear; "off": released since then.
        let mut m = Map::new();
        m.insert("on".into(), Dynamic::from(i64::from(l.energized)));
        m.insert("off".into(), Dynamic::from(i64::from(l.released)));
        m
    });
    engine.register_fn("clear_latch", |d: &mut Io| -> R<()> {
        c29u_op(d, |m, _| m.clear_latches())
    });
    engine.register_fn("watchdog", |d: &mut Io, seconds: i64| -> R<()> {
        set_watchdog(d, seconds as f64)
    });
    engine.register_fn("watchdog", |d: &mut Io, seconds: f64| -> R<()> {
        set_watchdog(d, seconds)
    });
    engine.register_fn("watchdog", |d: &mut Io| -> R<Map> {
        let info = c29u_op(d, |m, _| Ok(m.driver().watchdog()?))?;
        let mut map = Map::new();
        map.insert("enabled".into(), Dynamic::from(info.enabled));
        map.insert(
            "timeout_ms".into(),
            Dynamic::from(i64::from(info.timeout_tenths) * 100),
        );
        map.insert(
            "expired".into(),
            info.expired.map_or(Dynamic::UNIT, Dynamic::from),
        );
        Ok(map)
    });
    engine.register_fn("watchdog_off", |d: &mut Io| -> R<()> {
        c29u_op(d, |m, now| m.change_watchdog(None, now))
    });
    engine.register_get("safe_value", |d: &mut Io| -> R<i64> {
        c29u_op(d, |m, _| Ok(i64::from(m.driver().safe_value()?)))
    });
    setter(engine, "safe_value", |d: &mut Io, v: i64| -> R<()> {
        let v = byte("safe value", v)?;
        c29u_op(d, |m, _| m.change_safe_value(v))
    });
    engine.register_get("power_on_value", |d: &mut Io| -> R<i64> {
        c29u_op(d, |m, _| Ok(i64::from(m.driver().power_on_value()?)))
    });
    setter(engine, "power_on_value", |d: &mut Io, v: i64| -> R<()> {
        let v = byte("power-on value", v)?;
        c29u_op(d, |m, _| m.change_power_on_value(v))
    });
    engine.register_get("name", |d: &mut Io| -> R<String> {
        c29u_op(d, |m, _| Ok(m.driver().name()?))
    });
    engine.register_get("firmware", |d: &mut Io| -> R<String> {
        c29u_op(d, |m, _| Ok(m.driver().firmware()?.text))
    });
    engine.register_fn("reset", |d: &mut Io| -> R<()> {
        c29u_op(d, |m, _| m.reset_module())
    });
    engine.register_get("in_safe_mode", |d: &mut Io| -> R<bool> {
        c29u_op(d, |m, _| {
            if let Some(expired) = m.driver().watchdog()?.expired {
                return Ok(expired);
            }
            // The protocol cannot say: write the module's own outputs back, which only a
            // module in safe mode refuses.
            let now = m.driver().read_outputs()?;
            match m.driver().write_outputs(now) {
                Ok(()) => Ok(false),
                Err(C29uError::SafeMode { .. }) => Ok(true),
                Err(e) => Err(e.into()),
            }
        })
    });
    for (method, rise) in [("on_rise", true), ("on_fall", false)] {
        let a = arities.clone();
        engine.register_fn(method, move |d: &mut Io, ch: Dynamic, f: FnPtr| -> R<i64> {
            let c = channel(d, &ch, Way::Input)?;
            a.check(&f, method)?;
            d.read(Item::Input(c).mask());
            let source = if rise {
                Source::Rise { dev: d.idx, ch: c }
            } else {
                Source::Fall { dev: d.idx, ch: c }
            };
            let label = format!(
                "{}.{method} {}",
                d.name,
                d.names.shown(&format!("DI{c}"))
            );
            Ok(id_value(d.rt.subscribe(source, Rc::new(f), label)))
        });
    }
    let a = arities.clone();
    engine.register_fn(
        "on_counter",
        move |d: &mut Io, ch: Dynamic, threshold: i64, f: FnPtr| -> R<i64> {
            let c = channel(d, &ch, Way::Input)?;
            let Ok(t) = u16::try_from(threshold) else {
                return fail(format!(
                    "counter threshold {threshold} is not possible: the counters count 0-65535"
                ));
            };
            a.check(&f, "on_counter")?;
            d.read(Item::Counter(c).mask());
            let label = format!(
                "{}.on_counter {} >= {t}",
                d.name,
                d.names.shown(&format!("DI{c}"))
            );
            let source = Source::Counter {
                dev: d.idx,
                ch: c,
                threshold: t,
                armed: true,
            };
            Ok(id_value(d.rt.subscribe(source, Rc::new(f), label)))
        },
    );
}

/// A watchdog timeout from a script's seconds, to the nearest 0.1 s step (2.3 means 23
/// tenths); anything outside 0.1-25.5 s (and NaN) is refused before any arithmetic on it.
fn watchdog_timeout(seconds: f64) -> R<WatchdogTimeout> {
    let tenths = (seconds * 10.0).round();
    let t = (1.0..=255.0)
        .contains(&tenths)
        .then(|| WatchdogTimeout::from_tenths(tenths as u8))
        .flatten();
    t.map_or_else(
        || {
            fail(format!(
                "watchdog({seconds}) is not possible: use 0.1 to 25.5 seconds \
                 (watchdog_off() turns it off)"
            ))
        },
        Ok,
    )
}

fn set_watchdog(d: &Io, seconds: f64) -> R<()> {
    let t = watchdog_timeout(seconds)?;
    c29u_op(d, |m, now| m.change_watchdog(Some(t), now))
}

fn register_flow(engine: &mut Engine, rt: &Rt, arities: &Arities) {
    let (r, a) = (rt.clone(), arities.clone());
    engine.register_fn("every", move |d: Dynamic, f: FnPtr| -> R<i64> {
        let d = duration(&d)?;
        a.check(&f, "every")?;
        let id = r.every(d, Rc::new(f));
        id.map(id_value).or_else(|e| fail(e.to_string()))
    });
    let (r, a) = (rt.clone(), arities.clone());
    engine.register_fn("after", move |d: Dynamic, f: FnPtr| -> R<i64> {
        let d = duration(&d)?;
        a.check(&f, "after")?;
        let id = r.after(d, Rc::new(f));
        id.map(id_value).or_else(|e| fail(e.to_string()))
    });
    let (r, a) = (rt.clone(), arities.clone());
    engine.register_fn("cron", move |expr: &str, f: FnPtr| -> R<i64> {
        a.check(&f, "cron")?;
        let id = r.cron(expr, Rc::new(f));
        id.map(id_value).or_else(|e| fail(e.to_string()))
    });
    let r = rt.clone();
    engine.register_fn("cancel", move |id: i64| -> bool {
        u64::try_from(id).is_ok_and(|id| r.cancel(id))
    });
    let (r, a) = (rt.clone(), arities.clone());
    engine.register_fn("on_stop", move |f: FnPtr| -> R<i64> {
        a.check(&f, "on_stop")?;
        let id = r.on_stop(Rc::new(f));
        id.map(id_value).or_else(|e| fail(e.to_string()))
    });
    let (r, a) = (rt.clone(), arities.clone());
    engine.register_fn("on_reload", move |f: FnPtr| -> R<()> {
        a.check(&f, "on_reload")?;
        r.on_reload(Rc::new(f));
        Ok(())
    });
    let r = rt.clone();
    engine.register_fn("is_reload", move || r.is_reload());
    register_remote(engine, rt, arities);
    let r = rt.clone();
    engine.register_fn("stop", move || -> R<()> { stop(&r, 0) });
    let r = rt.clone();
    engine.register_fn("stop", move |code: i64| -> R<()> {
        if !(0..=255).contains(&code) {
            return fail(format!("stop({code}): an exit status is 0-255"));
        }
        stop(&r, code)
    });
    let r = rt.clone();
    engine.register_fn("now", move || r.wall_text());
    let r = rt.clone();
    engine.register_fn("uptime", move || {
        i64::try_from(r.uptime().as_millis()).unwrap_or(i64::MAX)
    });
    let r = rt.clone();
    engine.on_print(move |s| r.info(&format!("script: {s}")));
    let r = rt.clone();
    engine.on_debug(move |s, _, _| r.info(&format!("script: {s}")));
    let r = rt.clone();
    engine.register_fn("log", move |m: Dynamic| {
        r.info(&format!("script: {m}"));
    });
    let r = rt.clone();
    engine.register_fn("warn", move |m: Dynamic| {
        r.warn(&format!("script: {m}"));
    });
}

/// The longest command name `on_command` takes.
const MAX_COMMAND_NAME: usize = 64;

/// `on_command`, `on_message` and `mqtt_publish`: the script's side of the broker
/// (`service::mqtt` carries them; without `[mqtt]` nothing arrives and nothing goes).
fn register_remote(engine: &mut Engine, rt: &Rt, arities: &Arities) {
    use crate::runtime::handlers::Source;
    use crate::runtime::topic_filter::{check_filter, check_topic};
    let (r, a) = (rt.clone(), arities.clone());
    engine.register_fn("on_command", move |name: &str, f: FnPtr| -> R<i64> {
        let fits = !name.is_empty()
            && name.len() <= MAX_COMMAND_NAME
            && !name.contains(['/', '+', '#', '\0']);
        if !fits {
            return fail(format!(
                "on_command({name:?}, ..): a command name is 1-{MAX_COMMAND_NAME} bytes \
                 without '/', '+' or '#'"
            ));
        }
        a.check(&f, "on_command")?;
        let label = format!("on_command {name}");
        Ok(id_value(r.subscribe(
            Source::Command(name.to_string()),
            Rc::new(f),
            label,
        )))
    });
    let (r, a) = (rt.clone(), arities.clone());
    engine.register_fn("on_message", move |filter: &str, f: FnPtr| -> R<i64> {
        check_filter(filter).or_else(|e| fail(format!("on_message: {e}")))?;
        a.check(&f, "on_message")?;
        let label = format!("on_message {filter}");
        Ok(id_value(r.subscribe(
            Source::Message(filter.to_string()),
            Rc::new(f),
            label,
        )))
    });
    let r = rt.clone();
    engine.register_fn(
        "mqtt_publish",
        move |topic: &str, value: Dynamic| -> R<()> {
            check_topic(topic).or_else(|e| fail(format!("mqtt_publish: {e}")))?;
            let payload = if value.is_string() {
                value.to_string()
            } else {
                to_json(&value).to_string()
            };
            if payload.len() > crate::runtime::topic_filter::MAX_PAYLOAD {
                return fail(format!(
                    "mqtt_publish: a payload of {} bytes; at most {}",
                    payload.len(),
                    crate::runtime::topic_filter::MAX_PAYLOAD
                ));
            }
            let topic = topic.to_string();
            r.publish(topic, payload);
            Ok(())
        },
    );
}

/// `invariant(name, || bool)`: states what must hold after every tick's handlers.
fn register_invariant(
    engine: &mut Engine,
    rt: &Rt,
    arities: &Arities,
    file: &Rc<std::cell::RefCell<String>>,
) {
    let (r, a, file) = (rt.clone(), arities.clone(), Rc::clone(file));
    engine.register_fn(
        "invariant",
        move |ctx: NativeCallContext, name: &str, f: FnPtr| -> R<()> {
            a.check(&f, "invariant")?;
            let at = super::error::location(&file.borrow(), ctx.call_position());
            let added = r.add_invariant(name, Rc::new(f), at);
            added.or_else(|e| fail(e.to_string()))
        },
    );
    engine.register_fn("invariant", |_name: &str, v: Dynamic| -> R<()> {
        fail(format!(
            "invariant(name, check): the check must be a closure taking no parameters, such \
             as `|| io.outputs == 0`, not {}",
            v.type_name()
        ))
    });
}

/// `stop(code)`: asks the runner to stop, and ends the handler at once.
fn stop(rt: &Rt, code: i64) -> R<()> {
    rt.request_stop(code);
    end_handler()
}

/// Ends the handler under way at once, without a fault (`STOP_MARKER`).
fn end_handler<T>() -> R<T> {
    Err(
        EvalAltResult::ErrorTerminated(Dynamic::from(STOP_MARKER.to_string()), Position::NONE)
            .into(),
    )
}

fn number(v: &Dynamic, what: &str) -> R<f64> {
    if let Some(i) = v.clone().try_cast::<i64>() {
        Ok(i as f64)
    } else if let Some(f) = v.clone().try_cast::<f64>() {
        Ok(f)
    } else {
        fail(format!("{what} must be a number, not {}", v.type_name()))
    }
}

fn limits(map: &Map) -> R<Limits> {
    let mut l = Limits::default();
    for (key, value) in map {
        match key.as_str() {
            "min" => l.min = Some(number(value, "min")?),
            "max" => l.max = Some(number(value, "max")?),
            "unit" => l.unit = Some(value.to_string()),
            other => {
                return fail(format!(
                    "measure: unknown limit {other:?}; use #{{min, max, unit}}"
                ))
            }
        }
    }
    Ok(l)
}

fn register_records(engine: &mut Engine, rt: &Rt) {
    let r = rt.clone();
    engine.register_fn("record", move |name: &str, value: Dynamic| -> R<()> {
        r.record(name, to_json(&value));
        Ok(())
    });
    let measure = move |rt: &Rt, name: &str, value: &Dynamic, l: &Limits| -> R<bool> {
        let v = number(value, "a measured value")?;
        Ok(rt.measure(name, v, l))
    };
    let r = rt.clone();
    engine.register_fn(
        "measure",
        move |name: &str, value: Dynamic, l: Map| -> R<bool> {
            measure(&r, name, &value, &limits(&l)?)
        },
    );
    let r = rt.clone();
    engine.register_fn("measure", move |name: &str, value: Dynamic| -> R<bool> {
        measure(&r, name, &value, &Limits::default())
    });
}
