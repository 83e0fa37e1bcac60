//! The loop's own tests, in virtual time.

use super::contract::describe;
use super::tick::boundary_at_or_after;
use super::wait::SLEEP_SLICE;
use super::*;
use crate::config::{ErrorPolicy, WakeLatency};
use crate::device::cancel::CANCEL_SLICE;
use crate::runtime::devices::links::TransactionCounter;
use crate::runtime::exit;
use crate::runtime::handlers::{Call, STOP_BUDGET};
use crate::runtime::invariants::InvariantCheck;
use crate::runtime::log::Logger;
use crate::runtime::records::Records;
use crate::runtime::safety::END_TRIES;
use crate::runtime::state::Runtime;
use crate::time::clock::SharedClock;
use crate::time::clock::{Clock, VirtualClock};
use crate::time::zone::Zone;
use signal_hook::consts::SIGTERM;
use std::cell::RefCell;
use std::rc::Rc;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::Duration;

/// A program with one `every` timer whose handler takes `burn` of (virtual) time.
struct Burner {
    rt: Shared<()>,
    clock: VirtualClock,
    every: Duration,
    burn: Duration,
    calls: u32,
    fail_at: Option<u32>,
}

impl Program for Burner {
    type Handler = ();
    fn start(&mut self) -> Result<(), HandlerFault> {
        self.rt.borrow_mut().every(self.every, ()).unwrap();
        Ok(())
    }
    fn holds(&mut self, _check: &InvariantCheck<()>) -> Result<bool, HandlerFault> {
        // This program states no invariants.
        Ok(true)
    }
    fn call(&mut self, _call: &Call<()>) -> Result<(), HandlerFault> {
        self.calls += 1;
        self.clock.advance(self.burn);
        if self.fail_at == Some(self.calls) {
            return Err(HandlerFault {
                location: Some("x.rhai:1:1".into()),
                cause: "boom".into(),
                over_budget: false,
            });
        }
        Ok(())
    }
}

fn runner(every: Duration, burn: Duration, policy: ErrorPolicy) -> (Runner<Burner>, VirtualClock) {
    let clock = VirtualClock::at_epoch();
    let shared: SharedClock = Arc::new(clock.clone());
    let rt = Rc::new(RefCell::new(Runtime::new(
        Arc::clone(&shared),
        Zone::utc(),
        Vec::new(),
        Records::in_memory(),
        Logger::new(Arc::clone(&shared), Zone::utc(), false),
        TransactionCounter::default(),
        Duration::from_secs(1),
    )));
    rt.borrow_mut().log_mut().keep_lines();
    let program = Burner {
        rt: Rc::clone(&rt),
        clock: clock.clone(),
        every,
        burn,
        calls: 0,
        fail_at: None,
    };
    let options = RunOptions {
        period: Duration::from_millis(20),
        policy,
        end_after: None,
        stop_flag: Arc::default(),
        wake_latency: WakeLatency::Off,
    };
    let mut r = Runner::new(rt, program, options);
    r.start();
    (r, clock)
}

#[test]
fn overruns_are_counted_and_the_loop_keeps_its_phase() {
    let (mut r, clock) = runner(
        Duration::from_millis(20),
        Duration::from_millis(50),
        ErrorPolicy::Stop,
    );
    r.advance(Duration::from_millis(400));
    assert!(r.stats().overruns > 0);
    assert_eq!(
        r.next_deadline().as_nanos() % Duration::from_millis(20).as_nanos(),
        0,
        "deadlines stay on the 20 ms grid"
    );
    assert!(r.next_deadline() > clock.now().saturating_sub(Duration::from_millis(20)));
    assert!(r.stats().work.max() >= Duration::from_millis(50));
}

#[test]
fn after_an_overrun_the_next_tick_starts_at_once() {
    let (mut r, clock) = runner(
        Duration::from_millis(20),
        Duration::from_millis(50),
        ErrorPolicy::Stop,
    );
    r.advance(Duration::from_millis(100));
    assert!(r.stats().overruns > 0);
    assert!(
        r.next_deadline() <= clock.now(),
        "no sleep to the next boundary after a tick that ran late"
    );
}

#[test]
fn idle_ticks_are_skipped_when_no_handler_polls_inputs() {
    let (mut r, _clock) = runner(Duration::from_secs(1), Duration::ZERO, ErrorPolicy::Stop);
    r.advance(Duration::from_secs(10));
    assert_eq!(r.program().calls, 10);
    assert!(r.stats().ticks <= 13, "{} ticks for 10 s", r.stats().ticks);
    assert_eq!(r.stats().overruns, 0);
}

#[test]
fn restart_backs_off_doubling() {
    let (mut r, clock) = runner(
        Duration::from_millis(100),
        Duration::ZERO,
        ErrorPolicy::Restart,
    );
    r.program.fail_at = Some(1);
    r.advance(Duration::from_millis(100));
    assert_eq!(r.program().calls, 1);
    r.program.fail_at = Some(2);
    // Restarted after 1 s; its timer fires 100 ms later and fails again.
    r.advance(Duration::from_millis(1100));
    assert_eq!(r.program().calls, 2);
    r.advance(Duration::from_millis(1900));
    assert_eq!(r.program().calls, 2, "the second wait is 2 s");
    r.advance(Duration::from_millis(200));
    assert_eq!(r.program().calls, 3);
    assert!(r.status().is_none());
    let log = r.runtime().borrow().log_lines().join("\n");
    assert!(log.contains("x.rhai:1:1: in every 100ms: boom"), "{log}");
    assert!(clock.now() >= Duration::from_millis(3300));
}

/// A program with `timers` timers all due at 1 s, whose third call "receives" SIGTERM.
struct Signalled {
    rt: Shared<()>,
    timers: usize,
    flag: Arc<AtomicUsize>,
    calls: usize,
}

impl Program for Signalled {
    type Handler = ();
    fn start(&mut self) -> Result<(), HandlerFault> {
        let mut rt = self.rt.borrow_mut();
        rt.limit_timers(self.timers + 1);
        for _ in 0..self.timers {
            rt.every(Duration::from_secs(1), ()).unwrap();
        }
        Ok(())
    }
    fn holds(&mut self, _check: &InvariantCheck<()>) -> Result<bool, HandlerFault> {
        // This program states no invariants.
        Ok(true)
    }
    fn call(&mut self, _call: &Call<()>) -> Result<(), HandlerFault> {
        self.calls += 1;
        if self.calls == 3 {
            self.flag.store(SIGTERM as usize, Ordering::SeqCst);
        }
        Ok(())
    }
}

#[test]
fn a_signal_during_a_tick_of_many_timers_ends_the_run_before_the_next_handler() {
    let (r, _clock) = runner(Duration::from_secs(3600), Duration::ZERO, ErrorPolicy::Stop);
    let rt = Rc::clone(r.runtime());
    let flag: Arc<AtomicUsize> = Arc::default();
    let program = Signalled {
        rt: Rc::clone(&rt),
        timers: 10_000,
        flag: Arc::clone(&flag),
        calls: 0,
    };
    let options = RunOptions {
        period: Duration::from_millis(20),
        policy: ErrorPolicy::Stop,
        end_after: None,
        stop_flag: flag,
        wake_latency: WakeLatency::Off,
    };
    let mut r = Runner::new(rt, program, options);
    r.start();
    r.advance(Duration::from_secs(2));
    assert_eq!(r.program().calls, 3, "no handler after the signal");
    assert_eq!(r.status(), Some(exit::signal(SIGTERM)));
    let log = r.runtime().borrow().log_lines().join("\n");
    assert!(log.contains("stopping: SIGTERM received"), "{log}");
}

#[test]
fn a_refused_prompt_wakeup_request_is_logged_once_and_shown_by_stats() {
    let (mut r, _clock) = runner(Duration::from_secs(3600), Duration::ZERO, ErrorPolicy::Stop);
    let denied = std::io::Error::from_raw_os_error(libc::EPERM);
    r.note_prompt_wakeups(Err(denied));
    r.advance(Duration::from_secs(2));
    let log = r.runtime().borrow().log_lines().join("\n");
    assert_eq!(
        log.matches("prompt wake-ups (1 ns timer slack, short scheduler slice) refused (")
            .count(),
        1,
        "{log}"
    );
    let stats = r.stats().prompt_wakeups.clone().unwrap_or_default();
    assert!(stats.starts_with("refused ("), "{stats}");
}

#[test]
fn a_limits_cause_is_not_repeated_by_the_message() {
    let fault = HandlerFault {
        location: Some("s.rhai:3:5".into()),
        cause: "ran over its operation budget of 10 operations in one call (a runaway \
                loop?); a call that needs more can have it with --budget"
            .into(),
        over_budget: true,
    };
    let message = describe(&fault, "every 1s");
    assert!(
        message.starts_with("s.rhai:3:5: in every 1s: ran over"),
        "{message}"
    );
    assert_eq!(message.matches("budget").count(), 2, "{message}");
}

#[test]
fn boundaries() {
    let ms = Duration::from_millis;
    assert_eq!(boundary_at_or_after(ms(100), ms(20), ms(50)), ms(100));
    assert_eq!(boundary_at_or_after(ms(100), ms(20), ms(100)), ms(100));
    assert_eq!(boundary_at_or_after(ms(100), ms(20), ms(101)), ms(120));
    assert_eq!(boundary_at_or_after(ms(100), ms(20), ms(140)), ms(140));
}

/// A program that sets outputs, then panics in its handler (holding a borrow of the
/// runtime, as a binding would) or at its top level.
struct Panicker {
    rt: Shared<&'static str>,
    at_start: bool,
}

impl Program for Panicker {
    type Handler = &'static str;
    fn start(&mut self) -> Result<(), HandlerFault> {
        let mut rt = self.rt.borrow_mut();
        rt.set_outputs(crate::runtime::testing::IO, 0xF0);
        rt.every(Duration::from_millis(100), "boom").unwrap();
        rt.flush_outputs();
        assert!(!self.at_start, "a bug at the top level");
        Ok(())
    }
    fn holds(&mut self, _check: &InvariantCheck<&'static str>) -> Result<bool, HandlerFault> {
        // This program states no invariants.
        Ok(true)
    }
    fn call(&mut self, _call: &Call<&'static str>) -> Result<(), HandlerFault> {
        let _held = self.rt.borrow_mut();
        panic!("a bug in a binding");
    }
}

fn panicking(at_start: bool) -> (Runner<Panicker>, crate::runtime::testing::TestRig) {
    let mut r = crate::runtime::testing::TestRig::started();
    let rt = r.shared_runtime();
    let program = Panicker {
        rt: Rc::clone(&rt),
        at_start,
    };
    let options = RunOptions {
        period: Duration::from_millis(20),
        policy: ErrorPolicy::Restart,
        end_after: None,
        stop_flag: Arc::default(),
        wake_latency: WakeLatency::Off,
    };
    let mut runner = Runner::new(rt, program, options);
    runner.start();
    (runner, r)
}

#[test]
fn a_panic_in_a_handler_writes_the_safe_state_and_ends_with_70() {
    let (mut runner, r) = panicking(false);
    runner.advance(Duration::from_millis(60));
    assert_eq!(r.sim.outputs("io").unwrap(), 0xF0, "at work");
    runner.advance(Duration::from_millis(100));
    assert_eq!(runner.status(), Some(exit::INTERNAL));
    assert_eq!(r.sim.outputs("io").unwrap(), 0x05, "the safe value");
    assert_eq!(r.sim.relay("panel").unwrap(), 3, "the safe relay");
    assert!(
        r.sim.watchdog("io").unwrap().enabled,
        "the watchdog is left on"
    );
    let log = runner.runtime().borrow().log_lines().join("\n");
    assert!(
        log.contains("safe state (internal error): io outputs 0x05, panel relay 3"),
        "{log}"
    );
    assert!(
        log.contains("internal error (a bug in rigscript; please report it with this log): a bug in a binding; host watchdogs left on; exit status 70"),
        "{log}"
    );
}

#[test]
fn a_panic_at_the_top_level_ends_safe_too() {
    let (runner, r) = panicking(true);
    assert_eq!(runner.status(), Some(exit::INTERNAL));
    let log = runner.runtime().borrow().log_lines().join("\n");
    assert!(log.contains("io: outputs 0x05 -> 0xf0"), "{log}");
    assert_eq!(r.sim.outputs("io").unwrap(), 0x05);
}

/// A program whose timer reads a module's inputs.
struct Reader {
    rt: Shared<&'static str>,
}

impl Program for Reader {
    type Handler = &'static str;
    fn start(&mut self) -> Result<(), HandlerFault> {
        self.rt
            .borrow_mut()
            .every(Duration::from_millis(100), "read")
            .unwrap();
        Ok(())
    }
    fn holds(&mut self, _check: &InvariantCheck<&'static str>) -> Result<bool, HandlerFault> {
        // This program states no invariants.
        Ok(true)
    }
    fn call(&mut self, _call: &Call<&'static str>) -> Result<(), HandlerFault> {
        self.rt.borrow_mut().inputs(crate::runtime::testing::IO);
        Ok(())
    }
}

#[test]
fn a_sigterm_while_a_silent_module_is_waited_for_is_honoured_within_a_slice() {
    // A module that waits 1 s for each answer and tries 11 times: each exchange with it,
    // silent, would take 21 s (every try after the first waits out a settling second).
    let rig = crate::runtime::testing::RIG
        .replace("watchdog = \"1s\"\n", "timeout = \"1s\"\nretries = 10\n");
    let mut r = crate::runtime::testing::TestRig::new(&rig);
    r.rt.start_devices().unwrap();
    let rt = r.shared_runtime();
    let flag: Arc<AtomicUsize> = Arc::default();
    let program = Reader { rt: Rc::clone(&rt) };
    let options = RunOptions {
        period: Duration::from_millis(20),
        policy: ErrorPolicy::Stop,
        end_after: None,
        stop_flag: Arc::clone(&flag),
        wake_latency: WakeLatency::Off,
    };
    let mut runner = Runner::new(rt, program, options);
    runner.start();
    r.sim.set_gone("io", true).unwrap();
    // The first read starts at 100 ms; the signal comes 350 ms into its first wait.
    let signalled = Duration::from_millis(450);
    r.clock.set_at(signalled, flag, SIGTERM as usize);
    runner.advance(Duration::from_secs(1));
    // Stopped by the signal, and the safe state did not reach the silent module.
    assert_eq!(runner.status(), Some(exit::TROUBLE));
    // The wait is cut within a slice; then only the end's writes: END_TRIES tries of 1 s
    // with the silent module, each after the line has been silent a timeout more (the
    // cut request's answer could still come). The exchange it cut would have gone on for
    // 20 s more.
    let took = r.clock.now() - signalled;
    let tries = END_TRIES * 2;
    let bound = CANCEL_SLICE + Duration::from_secs(1) * tries;
    assert!(took <= bound, "{took:?}, more than {bound:?}");
    let log = runner.runtime().borrow().log_lines().join("\n");
    assert!(log.contains("stopping: SIGTERM received"), "{log}");
    assert!(log.contains("io: the safe state did not reach it"), "{log}");
    assert!(
        !log.contains("io: lost"),
        "a cut exchange is no loss: {log}"
    );
    assert!(
        log.contains("the safe state did not reach io: exit status 5"),
        "{log}"
    );
    assert_eq!(r.sim.relay("panel").unwrap(), 3, "the others get theirs");
}

/// A program that turns the panel's relay off its safe position and then has only a slow
/// timer: nothing in it makes the loop tick before that timer.
struct SlowTimer {
    rt: Shared<&'static str>,
}

impl Program for SlowTimer {
    type Handler = &'static str;
    fn start(&mut self) -> Result<(), HandlerFault> {
        let mut rt = self.rt.borrow_mut();
        rt.set_relay(crate::runtime::testing::PANEL, 5);
        rt.every(Duration::from_secs(30), "slow").unwrap();
        Ok(())
    }
    fn holds(&mut self, _check: &InvariantCheck<&'static str>) -> Result<bool, HandlerFault> {
        // This program states no invariants.
        Ok(true)
    }
    fn call(&mut self, _call: &Call<&'static str>) -> Result<(), HandlerFault> {
        Ok(())
    }
}

fn slow_timer(
    period: Duration,
    end_after: Option<Duration>,
) -> (Runner<SlowTimer>, crate::runtime::testing::TestRig) {
    let mut r = crate::runtime::testing::TestRig::started();
    let rt = r.shared_runtime();
    let program = SlowTimer { rt: Rc::clone(&rt) };
    let options = RunOptions {
        period,
        policy: ErrorPolicy::Stop,
        end_after,
        stop_flag: Arc::default(),
        wake_latency: WakeLatency::Off,
    };
    let mut runner = Runner::new(rt, program, options);
    runner.start();
    (runner, r)
}

#[test]
fn a_lost_devices_grace_end_holds_every_output_safe_at_once_whatever_the_period() {
    for period in [Duration::from_millis(20), Duration::from_secs(10)] {
        let (mut runner, r) = slow_timer(period, None);
        runner.advance(Duration::from_millis(100));
        assert_eq!(r.sim.relay("panel").unwrap(), 5, "at work");
        r.sim.set_gone("io", true).unwrap();
        // Lost at its next watchdog feed; held safe once lost for longer than grace (1 s).
        let step = Duration::from_millis(10);
        let started = r.clock.now();
        while r.sim.relay("panel").unwrap() != 3
            && r.clock.now() - started < Duration::from_secs(20)
        {
            runner.advance(step);
        }
        let held_at = r.clock.now();
        let lost_at = runner
            .runtime()
            .borrow()
            .devices
            .get(crate::runtime::testing::IO)
            .unwrap()
            .health()
            .lost_at
            .expect("io is lost");
        let log = runner.runtime().borrow().log_lines().join("\n");
        assert_eq!(r.sim.relay("panel").unwrap(), 3, "{period:?}: {log}");
        let grace = Duration::from_secs(1);
        assert!(
            held_at <= lost_at + grace + step,
            "{period:?}: lost at {lost_at:?}, the panel safe at {held_at:?}: {log}"
        );
        assert!(
            log.contains("every output is held at its safe state"),
            "{log}"
        );
    }
}

#[test]
fn the_end_of_for_is_honoured_to_the_sleep_slice_not_the_period() {
    let (mut runner, r) = slow_timer(Duration::from_secs(10), Some(Duration::from_secs(2)));
    let status = runner.run();
    assert_eq!(status, exit::OK);
    let ended = r.clock.now();
    assert!(
        ended >= Duration::from_secs(2) && ended <= Duration::from_secs(2) + SLEEP_SLICE,
        "ended at {ended:?}"
    );
    let log = runner.runtime().borrow().log_lines().join("\n");
    assert!(log.contains("stopping: ran for 2s"), "{log}");
}

/// A program with `handlers` on_stop handlers, each taking `burn` of virtual time; the
/// one numbered `signal_in` (if any) "receives" SIGINT meanwhile.
struct StopBurner {
    rt: Shared<()>,
    clock: VirtualClock,
    handlers: usize,
    burn: Duration,
    signal_in: Option<usize>,
    flag: Arc<AtomicUsize>,
    calls: usize,
}

impl Program for StopBurner {
    type Handler = ();
    fn start(&mut self) -> Result<(), HandlerFault> {
        let mut rt = self.rt.borrow_mut();
        for _ in 0..self.handlers {
            rt.on_stop(()).unwrap();
        }
        rt.every(Duration::from_secs(1), ()).unwrap();
        Ok(())
    }
    fn holds(&mut self, _check: &InvariantCheck<()>) -> Result<bool, HandlerFault> {
        // This program states no invariants.
        Ok(true)
    }
    fn call(&mut self, _call: &Call<()>) -> Result<(), HandlerFault> {
        self.calls += 1;
        self.clock.advance(self.burn);
        if self.signal_in == Some(self.calls) {
            self.flag.store(libc::SIGINT as usize, Ordering::SeqCst);
        }
        Ok(())
    }
}

fn stop_burner(
    handlers: usize,
    burn: Duration,
    signal_in: Option<usize>,
) -> (Runner<StopBurner>, VirtualClock) {
    let (r, clock) = runner(Duration::from_secs(3600), Duration::ZERO, ErrorPolicy::Stop);
    let rt = Rc::clone(r.runtime());
    let flag: Arc<AtomicUsize> = Arc::default();
    let program = StopBurner {
        rt: Rc::clone(&rt),
        clock: clock.clone(),
        handlers,
        burn,
        signal_in,
        flag: Arc::clone(&flag),
        calls: 0,
    };
    let options = RunOptions {
        period: Duration::from_millis(20),
        policy: ErrorPolicy::Stop,
        end_after: None,
        stop_flag: flag,
        wake_latency: WakeLatency::Off,
    };
    let mut r = Runner::new(rt, program, options);
    r.start();
    (r, clock)
}

#[test]
fn on_stop_handlers_share_one_budget_and_the_rest_are_skipped() {
    let (mut r, clock) = stop_burner(100, Duration::from_millis(300), None);
    r.advance(Duration::from_millis(100));
    let stopped_at = clock.now();
    r.signal_stop();
    // 300 ms each: the seventh starts before 2 s are spent and ends past them.
    assert_eq!(r.program().calls, 7);
    assert!(clock.now() - stopped_at <= STOP_BUDGET + Duration::from_millis(300));
    let log = r.runtime().borrow().log_lines().join("\n");
    assert!(
        log.contains("the on_stop handlers' 2s are spent: 93 on_stop handler(s) skipped, straight to the safe state"),
        "{log}"
    );
    assert_eq!(
        r.status(),
        Some(exit::TROUBLE),
        "skipped handlers are failed ones"
    );
}

#[test]
fn a_second_signal_while_stopping_skips_the_remaining_on_stop_handlers() {
    let (mut r, _clock) = stop_burner(5, Duration::from_millis(10), Some(2));
    r.advance(Duration::from_millis(100));
    r.signal_stop();
    assert_eq!(r.program().calls, 2, "none after the second signal");
    let log = r.runtime().borrow().log_lines().join("\n");
    let skipped = log
        .find("SIGINT received while stopping: 3 on_stop handler(s) skipped, straight to the safe state")
        .unwrap_or_else(|| panic!("{log}"));
    let end = log
        .find("stopped; exit status 143")
        .unwrap_or_else(|| panic!("{log}"));
    assert!(skipped < end, "{log}");
    assert_eq!(r.status(), Some(exit::signal(SIGTERM)));
}

#[test]
fn a_stalled_subscriber_costs_no_tick_and_the_end_figures_say_what_it_lost() {
    let (mut r, _clock) = runner(
        Duration::from_millis(20),
        Duration::from_millis(1),
        ErrorPolicy::Stop,
    );
    // Attached and never read.
    let stalled = r.events().subscribe("stalled", 4).unwrap();
    r.advance(Duration::from_secs(1));
    assert!(r.stats().ticks >= 49, "{} ticks", r.stats().ticks);
    assert_eq!(r.stats().overruns, 0);
    let lost = stalled.dropped();
    assert!(lost >= 45, "{lost}");
    drop(stalled);
    // The figures `--stats` prints are the snapshot's, and remember a consumer gone.
    let figures = r.snapshot();
    assert_eq!(figures.ticks.count, r.stats().ticks);
    assert!(figures.dropped.is_empty(), "{:?}", figures.dropped);
    let text = figures.stats_text().to_string();
    assert!(
        text.starts_with(&format!("ticks: {}\n", r.stats().ticks)),
        "{text}"
    );
    assert!(
        text.contains(&format!(
            "events dropped: {lost} (by the event stream's consumers"
        )),
        "{text}"
    );
    assert!(text.contains("overruns: 0\n"), "{text}");
}
