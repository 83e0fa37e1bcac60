//! Behaviour of the TRP-C29U model in virtual time.

use super::*;
use crate::protocol::c29u_ascii::{ConfigReport, DataFormat, SynchronizedData};
use crate::time::clock::VirtualClock;
use std::sync::Arc;

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// A data format byte of 8-3 as the protocol reads it.
fn format(dd: u8) -> DataFormat {
    DataFormat::from_byte(dd).unwrap()
}

fn module(protocol: Protocol) -> (C29uModel, VirtualClock) {
    let clock = VirtualClock::at_epoch();
    let m = C29uModel::new(protocol, Arc::new(clock.clone()), Eeprom::factory());
    (m, clock)
}

fn ascii() -> (C29uModel, VirtualClock) {
    module(Protocol::Ascii)
}

/// A fresh, unique directory under the system temp dir, removed on drop.
struct TempDir(PathBuf);

impl TempDir {
    fn new(tag: &str) -> Self {
        use std::sync::atomic::{AtomicU32, Ordering};
        static SEQ: AtomicU32 = AtomicU32::new(0);
        let n = SEQ.fetch_add(1, Ordering::Relaxed);
        let nanos = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map(|d| d.as_nanos())
            .unwrap_or(0);
        let dir = std::env::temp_dir().join(format!(
            "rigscript-c29u-{tag}-{}-{n}-{nanos}",
            std::process::id()
        ));
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    fn file(&self, name: &str) -> PathBuf {
        self.0.join(name)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

// ---- power on and config ------------------------------------------------------------------

#[test]
fn factory_module_powers_on_with_documented_defaults() {
    let (mut m, _) = ascii();
    assert_eq!(m.protocol(), Protocol::Ascii);
    assert_eq!(m.config(), ModuleConfig::factory());
    assert_eq!(m.config().id, 1);
    assert_eq!(m.config().baud_code, 0x06);
    assert_eq!(m.config().baud_rate(), Some(9600));
    assert_eq!(m.name(), "TRPC29");
    assert_eq!(m.outputs(), 0);
    assert_eq!(m.inputs(), 0);
    assert_eq!(m.inputs_wire(), 0xFF);
    assert_eq!(m.counters(), [0; 8]);
    assert_eq!(m.led_mode(), 0);
    assert_eq!(
        m.watchdog(),
        WatchdogStatus {
            enabled: false,
            timeout_tenths: 0,
            expired: false
        }
    );
    assert_eq!(FIRMWARE_MODEL, "C29M");
    assert_eq!(
        (FIRMWARE_DATE.year, FIRMWARE_DATE.month, FIRMWARE_DATE.day),
        (9, 7, 3)
    );
}

#[test]
fn factory_data_format_reads_back_as_03_like_8_12() {
    // 8-12: "$012" -> "!01400603": DIO type 40, 9600 baud, format 03 (rising, no checksum, C29U).
    let cfg = ModuleConfig::factory();
    assert_eq!(cfg.report().module_type, 0x40);
    assert_eq!(cfg.report().baud_code, 0x06);
    assert_eq!(cfg.data_format().to_byte(), 0x00);
    assert_eq!(cfg.report().format, 0x03);
}

#[test]
fn data_format_bits_follow_8_3() {
    let cfg = ModuleConfig::from_parts(0x03, 0x05, format(0xC1)).unwrap();
    assert_eq!(cfg.id, 3);
    assert_eq!(cfg.baud_rate(), Some(4800));
    assert_eq!(cfg.counter_edge, CounterEdge::Falling);
    assert!(cfg.checksum);
    assert!(cfg.hex_counters);
    assert_eq!(cfg.data_format().to_byte(), 0xC1);
    // $ID2 shows the edge and checksum bits and the model code, not the hex bit.
    assert_eq!(cfg.report().format, 0xC3);
    // 8-3's example "%0101400601": ID 01, 9600, counter mode hex.
    let hex = ModuleConfig::from_parts(0x01, 0x06, format(0x01)).unwrap();
    assert!(hex.hex_counters && !hex.checksum);
    assert_eq!(hex.counter_edge, CounterEdge::Rising);
    // 8-3's first example "%0001400600": new ID 01, 9600, checksum disabled.
    assert_eq!(
        ModuleConfig::from_parts(0x01, 0x06, format(0x00)).unwrap(),
        ModuleConfig::factory()
    );
}

#[test]
fn from_parts_rejects_bad_baud_and_unused_format_bits() {
    assert!(matches!(
        ModuleConfig::from_parts(1, 0x02, format(0)),
        Err(C29uModelError::BadValue(_))
    ));
    assert!(matches!(
        ModuleConfig::from_parts(1, 0x0B, format(0)),
        Err(C29uModelError::BadValue(_))
    ));
    // The reserved bits are the protocol's to refuse: such a format is no `DataFormat`.
    assert_eq!(DataFormat::from_byte(0x03), None);
}

#[test]
fn baud_codes_map_to_the_8_2_table() {
    let table = [
        (0x03, 1200),
        (0x04, 2400),
        (0x05, 4800),
        (0x06, 9600),
        (0x07, 19200),
        (0x08, 38400),
        (0x09, 57600),
        (0x0A, 115_200),
    ];
    for (code, rate) in table {
        assert_eq!(baud_rate(code), Some(rate));
    }
    assert_eq!(baud_rate(0x00), None);
    assert_eq!(baud_rate(0x0B), None);
    assert_eq!(baud_rate(0xFF), None);
}

#[test]
fn set_config_validates_and_stores() {
    let (mut m, _) = ascii();
    let mut cfg = ModuleConfig::factory();
    cfg.baud_code = 0x0B;
    assert!(matches!(
        m.set_config(cfg),
        Err(C29uModelError::BadValue(_))
    ));
    assert_eq!(
        m.config(),
        ModuleConfig::factory(),
        "rejected config not stored"
    );

    cfg.baud_code = 0x0A;
    cfg.id = 0;
    cfg.checksum = true;
    m.set_config(cfg).unwrap();
    assert_eq!(m.config(), cfg, "ASCII takes ID 00");
    m.reset();
    assert_eq!(m.config(), cfg, "config survives a reset");

    cfg.id = 0xFF;
    m.set_config(cfg).unwrap();
    assert_eq!(m.config().id, 0xFF, "ASCII takes ID FF");
}

#[test]
fn modbus_ids_are_1_to_247() {
    let (mut m, _) = module(Protocol::Modbus);
    let mut cfg = ModuleConfig::factory();
    for bad in [0u8, 248, 255] {
        cfg.id = bad;
        assert!(matches!(
            m.set_config(cfg),
            Err(C29uModelError::BadValue(_))
        ));
    }
    for good in [1u8, 2, 247] {
        cfg.id = good;
        m.set_config(cfg).unwrap();
        assert_eq!(m.config().id, good);
    }
}

// ---- inputs, counters, latches -----------------------------------------------------------

#[test]
fn inputs_on_the_wire_are_active_low() {
    let (mut m, _) = ascii();
    // 8-11 "!0121CF": DI4 and DI5 energized is CF on the wire.
    m.set_inputs(0b0011_0000);
    assert_eq!(m.inputs(), 0x30);
    assert_eq!(m.inputs_wire(), 0xCF);
    // 10-17 "01 01 01 DF": CH5 enabled.
    m.set_inputs(0b0010_0000);
    assert_eq!(m.inputs_wire(), 0xDF);
}

#[test]
fn counters_count_rising_edges_by_default() {
    let (mut m, _) = ascii();
    m.set_inputs(0b0000_0101); // DI0, DI2 energized: rising
    assert_eq!(m.counters(), [1, 0, 1, 0, 0, 0, 0, 0]);
    m.set_inputs(0b0000_0101); // no change
    assert_eq!(m.counters(), [1, 0, 1, 0, 0, 0, 0, 0]);
    m.set_inputs(0b0000_0001); // DI2 released: falling, not counted
    assert_eq!(m.counters(), [1, 0, 1, 0, 0, 0, 0, 0]);
    m.set_inputs(0b0000_0110); // DI0 falls, DI1 and DI2 rise
    assert_eq!(m.counters(), [1, 1, 2, 0, 0, 0, 0, 0]);
    assert_eq!(m.counter(2), Ok(2));
}

#[test]
fn counters_count_falling_edges_when_configured() {
    let (mut m, _) = ascii();
    let mut cfg = m.config();
    cfg.counter_edge = CounterEdge::Falling;
    m.set_config(cfg).unwrap();
    m.set_inputs(0b1000_0001);
    assert_eq!(m.counters(), [0; 8], "rising edges not counted");
    m.set_inputs(0b0000_0001);
    assert_eq!(m.counter(7), Ok(1));
    assert_eq!(m.counter(0), Ok(0));
    m.set_inputs(0);
    assert_eq!(m.counter(0), Ok(1));
}

#[test]
fn counter_wraps_from_65535_to_0() {
    let (mut m, _) = ascii();
    m.pulse(3, 65_535).unwrap();
    assert_eq!(m.counter(3), Ok(65_535));
    m.set_inputs(0b1000);
    assert_eq!(m.counter(3), Ok(0));
    m.set_inputs(0);
    m.set_inputs(0b1000);
    assert_eq!(m.counter(3), Ok(1));
    // Many wraps at once: only n mod 65536 shows.
    m.pulse(3, 3 * 65_536 + 10).unwrap();
    assert_eq!(m.counter(3), Ok(11));
    m.pulse(4, u32::MAX).unwrap();
    assert_eq!(m.counter(4), Ok(65_535));
}

#[test]
fn pulses_count_on_either_edge_and_leave_the_level() {
    let (mut m, _) = ascii();
    m.pulse(1, 5).unwrap();
    assert_eq!(m.counter(1), Ok(5));
    assert_eq!(m.inputs(), 0, "ends released");
    m.set_inputs(0b10); // now energized: rising edge counts
    assert_eq!(m.counter(1), Ok(6));
    m.pulse(1, 2).unwrap();
    assert_eq!(m.counter(1), Ok(8));
    assert_eq!(m.inputs(), 0b10, "a pulse from energized ends energized");

    let mut cfg = m.config();
    cfg.counter_edge = CounterEdge::Falling;
    m.set_config(cfg).unwrap();
    m.pulse(6, 4).unwrap();
    assert_eq!(m.counter(6), Ok(4));
    m.pulse(6, 0).unwrap();
    assert_eq!(m.counter(6), Ok(4), "zero pulses do nothing");
}

#[test]
fn pulses_match_the_same_edges_done_by_hand() {
    let (mut a, _) = ascii();
    let (mut b, _) = ascii();
    a.pulse(2, 3).unwrap();
    for _ in 0..3 {
        b.set_inputs(0b100);
        b.set_inputs(0);
    }
    assert_eq!(a.counters(), b.counters());
    assert_eq!(a.latched_low(), b.latched_low());
    assert_eq!(a.latched_high(), b.latched_high());
    assert_eq!(a.inputs(), b.inputs());
}

#[test]
fn counters_clear_one_or_all() {
    let (mut m, _) = ascii();
    for ch in 0..8 {
        m.pulse(ch, u32::from(ch) + 1).unwrap();
    }
    m.clear_counter(2).unwrap();
    assert_eq!(m.counters(), [1, 2, 0, 4, 5, 6, 7, 8]);
    m.clear_counters();
    assert_eq!(m.counters(), [0; 8]);
}

#[test]
fn unsaved_counts_are_lost_on_reset_and_power_cycle() {
    let (mut m, _) = ascii();
    m.pulse(0, 23).unwrap();
    m.reset();
    assert_eq!(m.counter(0), Ok(0));
    m.pulse(0, 9).unwrap();
    m.power_cycle();
    assert_eq!(m.counter(0), Ok(0));
}

#[test]
fn saved_counts_come_back_after_reset_like_8_8() {
    // 8-8: "#01CS" then power fail or reset, "#010" -> "!0100187".
    let (mut m, _) = ascii();
    m.pulse(0, 187).unwrap();
    m.save_counters().unwrap();
    m.pulse(0, 13).unwrap();
    assert_eq!(m.counter(0), Ok(200));
    m.power_cycle();
    assert_eq!(m.counter(0), Ok(187));
    m.pulse(0, 1).unwrap();
    m.reset();
    assert_eq!(m.counter(0), Ok(187));
}

#[test]
fn clearing_without_saving_reloads_the_old_value() {
    // 8-6 / 8-7: after a clear, save again or the module loads the old value at reset.
    let (mut m, _) = ascii();
    m.pulse(5, 40).unwrap();
    m.save_counters().unwrap();
    m.clear_counter(5).unwrap();
    assert_eq!(m.counter(5), Ok(0));
    m.reset();
    assert_eq!(m.counter(5), Ok(40));
    m.clear_counters();
    m.save_counters().unwrap();
    m.reset();
    assert_eq!(m.counter(5), Ok(0));
}

#[test]
fn latches_set_by_changes_and_cleared() {
    let (mut m, _) = ascii();
    assert_eq!((m.latched_low(), m.latched_high()), (0, 0));
    m.set_inputs(0b0000_0010); // DI1 energized: wire goes to 0
    assert_eq!(m.latched_low(), 0b0000_0010);
    assert_eq!(m.latched_high(), 0);
    m.set_inputs(0); // released: wire back to 1; latched low stays
    assert_eq!(m.latched_low(), 0b0000_0010);
    assert_eq!(m.latched_high(), 0b0000_0010);
    m.clear_latches();
    assert_eq!((m.latched_low(), m.latched_high()), (0, 0));
}

#[test]
fn a_keystroke_between_two_reads_is_caught_by_the_latch() {
    // 8-9: $ID6 at A and B shows no key; the latch shows the stroke in between.
    let (mut m, _) = ascii();
    let at_a = m.inputs_wire();
    m.pulse(1, 1).unwrap();
    let at_b = m.inputs_wire();
    assert_eq!(at_a, at_b);
    assert_eq!(m.latched_low(), 0b10, "8-9's DI1 latched: first byte 02");
}

#[test]
fn a_level_held_across_the_clear_does_not_latch() {
    let (mut m, _) = ascii();
    m.set_inputs(0b1);
    m.clear_latches();
    m.set_inputs(0b1);
    assert_eq!((m.latched_low(), m.latched_high()), (0, 0));
    m.set_inputs(0);
    assert_eq!((m.latched_low(), m.latched_high()), (0, 1));
}

#[test]
fn latches_are_lost_on_reset() {
    let (mut m, _) = ascii();
    m.pulse(4, 1).unwrap();
    m.reset();
    assert_eq!((m.latched_low(), m.latched_high()), (0, 0));
}

#[test]
fn inputs_survive_a_power_cycle_without_counting() {
    let (mut m, _) = ascii();
    m.set_inputs(0b11);
    m.power_cycle();
    assert_eq!(m.inputs(), 0b11, "field wiring does not change");
    assert_eq!(m.counters(), [0; 8]);
    m.set_inputs(0b11);
    assert_eq!(m.counters(), [0; 8]);
}

#[test]
fn channels_outside_0_to_7_are_bad_channel() {
    let (mut m, _) = ascii();
    for ch in [8u8, 9, 15, 255] {
        assert_eq!(m.counter(ch), Err(C29uModelError::BadChannel(ch)));
        assert_eq!(m.clear_counter(ch), Err(C29uModelError::BadChannel(ch)));
        assert_eq!(m.pulse(ch, 1), Err(C29uModelError::BadChannel(ch)));
        assert_eq!(
            m.write_output(ch, true),
            Err(C29uModelError::BadChannel(ch))
        );
    }
    assert_eq!(m.outputs(), 0);
    assert_eq!(m.counters(), [0; 8]);
}

// ---- outputs ------------------------------------------------------------------------------

#[test]
fn outputs_by_byte_and_by_bit() {
    let (mut m, _) = ascii();
    m.write_outputs(0x2F).unwrap(); // 8-4 "#010A2F"
    assert_eq!(m.outputs(), 0x2F);
    m.write_outputs(0xA8).unwrap(); // 8-4 "#0100A8"
    assert_eq!(m.outputs(), 0xA8);
    m.write_outputs(0).unwrap();
    m.write_output(0, true).unwrap(); // "#011001"
    m.write_output(2, true).unwrap(); // "#011201"
    assert_eq!(m.outputs(), 0b101);
    m.write_output(7, true).unwrap();
    m.write_output(7, false).unwrap(); // "#011700"
    assert_eq!(m.outputs(), 0b101);
}

#[test]
fn power_on_value_is_driven_after_reset_and_power_cycle() {
    // 8-24: "#010013" then "~015P": after power fail or reset the module loads 13.
    let (mut m, _) = ascii();
    m.write_outputs(0x13).unwrap();
    m.save_outputs_as_power_on().unwrap();
    assert_eq!(m.power_on_value(), 0x13);
    m.write_outputs(0xFF).unwrap();
    m.reset();
    assert_eq!(m.outputs(), 0x13);
    m.write_outputs(0x00).unwrap();
    m.power_cycle();
    assert_eq!(m.outputs(), 0x13);
    // 10-11: "01 46 27 01 00" then reset -> DO = 01.
    m.set_power_on_value(0x01).unwrap();
    assert_eq!(m.outputs(), 0x13, "setting the value does not drive DO");
    m.reset();
    assert_eq!(m.outputs(), 0x01);
}

#[test]
fn save_outputs_as_safe_stores_the_current_do() {
    let (mut m, _) = ascii();
    m.write_outputs(0x14).unwrap();
    m.save_outputs_as_safe().unwrap();
    assert_eq!(m.safe_value(), 0x14);
    m.set_safe_value(0x08).unwrap();
    assert_eq!(m.safe_value(), 0x08);
    assert_eq!(
        m.outputs(),
        0x14,
        "setting the safe value does not drive DO"
    );
}

// ---- watchdog -----------------------------------------------------------------------------

#[test]
fn watchdog_fires_to_the_safe_value_and_refuses_writes() {
    // 10-13: safe value 14, watchdog 1.8 s, wait until DO becomes 14.
    let (mut m, clock) = ascii();
    m.set_safe_value(0x14).unwrap();
    m.write_outputs(0xFF).unwrap();
    m.set_watchdog(0x12).unwrap();
    assert_eq!(
        m.watchdog(),
        WatchdogStatus {
            enabled: true,
            timeout_tenths: 0x12,
            expired: false
        }
    );
    clock.advance(ms(1799));
    assert!(!m.in_safe_mode());
    assert_eq!(m.outputs(), 0xFF);
    clock.advance(ms(1));
    assert_eq!(m.outputs(), 0x14, "&self getter sees the expiry at once");
    assert!(m.in_safe_mode());
    assert_eq!(m.outputs(), 0x14);
    assert!(m.watchdog().expired);
    assert_eq!(m.write_outputs(0x01), Err(C29uModelError::SafeMode));
    assert_eq!(m.write_output(0, true), Err(C29uModelError::SafeMode));
    assert_eq!(m.outputs(), 0x14);
}

#[test]
fn a_write_after_the_deadline_is_refused_even_without_a_poll() {
    let (mut m, clock) = ascii();
    m.set_watchdog(1).unwrap();
    clock.advance(ms(5000));
    assert_eq!(m.write_outputs(0x55), Err(C29uModelError::SafeMode));
    assert_eq!(m.outputs(), 0);
}

#[test]
fn host_ok_keeps_the_watchdog_alive() {
    let (mut m, clock) = ascii();
    m.set_watchdog(5).unwrap(); // 0.5 s
    m.write_outputs(0x0F).unwrap();
    // 100 timeouts' worth of time, host OK every 0.4 s.
    for _ in 0..125 {
        clock.advance(ms(400));
        m.host_ok();
    }
    assert!(!m.in_safe_mode());
    assert_eq!(m.outputs(), 0x0F);
    m.write_outputs(0xF0).unwrap();
    clock.advance(ms(500));
    assert!(m.in_safe_mode(), "stops being fed: fires");
}

#[test]
fn other_commands_do_not_feed_the_watchdog() {
    let (mut m, clock) = ascii();
    m.set_watchdog(5).unwrap();
    for _ in 0..4 {
        clock.advance(ms(200));
        m.write_outputs(0x01).ok();
        let _ = m.counters();
        m.clear_latches();
        let _ = m.state();
    }
    assert!(m.in_safe_mode());
}

#[test]
fn host_ok_does_not_leave_safe_mode() {
    let (mut m, clock) = ascii();
    m.set_watchdog(1).unwrap();
    clock.advance(ms(100));
    m.host_ok();
    assert!(m.in_safe_mode());
    assert_eq!(m.write_outputs(1), Err(C29uModelError::SafeMode));
}

#[test]
fn disabling_the_watchdog_leaves_safe_mode() {
    let (mut m, clock) = ascii();
    m.set_safe_value(0x0A).unwrap();
    m.write_outputs(0xF0).unwrap();
    m.set_watchdog(1).unwrap();
    clock.advance(ms(150));
    assert!(m.in_safe_mode());
    m.set_watchdog(0).unwrap();
    assert_eq!(
        m.watchdog(),
        WatchdogStatus {
            enabled: false,
            timeout_tenths: 0,
            expired: false
        }
    );
    assert_eq!(
        m.outputs(),
        0x0A,
        "DO stays at the safe value until written"
    );
    m.write_outputs(0x33).unwrap();
    assert_eq!(m.outputs(), 0x33);
    clock.advance(ms(100_000));
    assert!(!m.in_safe_mode(), "disabled watchdog never fires");
}

#[test]
fn a_new_timeout_in_safe_mode_keeps_safe_mode() {
    let (mut m, clock) = ascii();
    m.set_watchdog(1).unwrap();
    clock.advance(ms(100));
    m.set_watchdog(50).unwrap();
    let wd = m.watchdog();
    assert!(wd.enabled && wd.expired);
    assert_eq!(wd.timeout_tenths, 50);
    assert_eq!(m.write_outputs(1), Err(C29uModelError::SafeMode));
}

#[test]
fn setting_a_timeout_restarts_the_countdown() {
    let (mut m, clock) = ascii();
    m.set_watchdog(10).unwrap();
    clock.advance(ms(900));
    m.set_watchdog(10).unwrap();
    clock.advance(ms(900));
    assert!(!m.in_safe_mode());
    clock.advance(ms(100));
    assert!(m.in_safe_mode());
}

#[test]
fn the_longest_timeout_is_25_5_s() {
    // 8-19: "~01WEFF" sets 25.5 s.
    let (mut m, clock) = ascii();
    m.set_watchdog(0xFF).unwrap();
    clock.advance(ms(25_499));
    assert!(!m.in_safe_mode());
    clock.advance(ms(1));
    assert!(m.in_safe_mode());
}

#[test]
fn watchdog_mode_survives_reset_and_restarts_counting() {
    let (mut m, clock) = ascii();
    m.set_watchdog(10).unwrap();
    clock.advance(ms(900));
    m.reset();
    assert_eq!(
        m.watchdog().timeout_tenths,
        10,
        "reset keeps the mode (8-19)"
    );
    clock.advance(ms(900));
    assert!(!m.in_safe_mode(), "countdown restarted by the reset");
    clock.advance(ms(100));
    assert!(m.in_safe_mode());
}

#[test]
fn safe_mode_persists_across_reset_and_power_cycle() {
    // Section 5, fail-safe reading: DO unchanged until the watchdog is disabled.
    let (mut m, clock) = ascii();
    m.set_safe_value(0x21).unwrap();
    m.set_power_on_value(0x80).unwrap();
    m.set_watchdog(2).unwrap();
    clock.advance(ms(200));
    assert!(m.in_safe_mode());
    m.reset();
    assert!(m.in_safe_mode());
    assert_eq!(m.outputs(), 0x21, "safe value, not the power-on value");
    assert_eq!(m.write_outputs(0), Err(C29uModelError::SafeMode));
    m.power_cycle();
    assert!(m.in_safe_mode());
    assert_eq!(m.outputs(), 0x21);
    m.set_watchdog(0).unwrap();
    m.reset();
    assert!(!m.in_safe_mode());
    assert_eq!(m.outputs(), 0x80, "out of safe mode, power-on value again");
}

#[test]
fn a_deadline_passed_before_the_reset_still_fires() {
    let (mut m, clock) = ascii();
    m.set_safe_value(0x05).unwrap();
    m.set_watchdog(1).unwrap();
    clock.advance(ms(500));
    m.reset(); // the module had fired before the reset came
    assert!(m.in_safe_mode());
    assert_eq!(m.outputs(), 0x05);
}

// ---- name, LED, reset flag, snapshot -------------------------------------------------------

#[test]
fn name_can_be_changed_like_8_17() {
    let (mut m, _) = ascii();
    m.set_name("ABCDE").unwrap();
    assert_eq!(m.name(), "ABCDE");
    m.power_cycle();
    assert_eq!(m.name(), "ABCDE", "name is in EEPROM");
    m.set_name("X").unwrap();
    m.set_name("ABCDEF").unwrap();
    assert_eq!(m.name(), "ABCDEF");
    for bad in ["", "ABCDEFG", "AB\rC", "é"] {
        assert!(
            matches!(m.set_name(bad), Err(C29uModelError::BadValue(_))),
            "{bad:?}"
        );
    }
    assert_eq!(m.name(), "ABCDEF");
}

#[test]
fn led_mode_is_0_or_1() {
    let (mut m, _) = ascii();
    m.set_led_mode(1).unwrap();
    assert_eq!(m.led_mode(), 1);
    assert!(matches!(
        m.set_led_mode(2),
        Err(C29uModelError::BadValue(_))
    ));
    assert_eq!(m.led_mode(), 1);
    m.reset();
    assert_eq!(m.led_mode(), 1);
}

#[test]
fn reset_flag_is_read_once() {
    let (mut m, _) = ascii();
    assert!(m.take_reset_flag(), "set at power on");
    assert!(!m.take_reset_flag());
    m.reset();
    assert!(m.take_reset_flag());
    assert!(!m.take_reset_flag());
    m.power_cycle();
    assert!(m.take_reset_flag());
    assert!(!m.take_reset_flag());
}

#[test]
fn synchronized_data_is_fresh_then_stale() {
    // 8-26: after #**, $ID4 answers A=1 once, then A=0.
    let (mut m, _) = ascii();
    assert_eq!(m.read_synchronized(), Err(C29uModelError::NotSynchronized));
    m.write_outputs(0x01).unwrap();
    m.set_inputs(0xF1); // wire 0E, like the "!1010E00" example
    m.synchronize();
    m.write_outputs(0xFF).unwrap();
    m.set_inputs(0);
    let first = m.read_synchronized().unwrap();
    assert_eq!(
        first,
        SynchronizedData {
            fresh: true,
            outputs: 0x01,
            inputs_wire: 0x0E
        }
    );
    let second = m.read_synchronized().unwrap();
    assert_eq!(
        second,
        SynchronizedData {
            fresh: false,
            ..first
        }
    );
    m.synchronize();
    let third = m.read_synchronized().unwrap();
    assert!(third.fresh);
    assert_eq!((third.outputs, third.inputs_wire), (0xFF, 0xFF));
}

#[test]
fn synchronized_data_is_lost_on_reset() {
    let (mut m, _) = ascii();
    m.synchronize();
    m.reset();
    assert_eq!(m.read_synchronized(), Err(C29uModelError::NotSynchronized));
}

// ---- state ----------------------------------------------------------------------------------

#[test]
fn state_json_has_exactly_the_control_line_shape() {
    let (mut m, clock) = module(Protocol::Modbus);
    let mut cfg = m.config();
    cfg.id = 7;
    m.set_config(cfg).unwrap();
    m.write_outputs(0x36).unwrap();
    m.set_inputs(0b0010_0000);
    m.pulse(0, 3).unwrap();
    m.set_safe_value(0x14).unwrap();
    m.set_power_on_value(0x08).unwrap();
    m.set_name("RIG1").unwrap();
    m.set_watchdog(15).unwrap();

    let v = serde_json::to_value(m.state()).unwrap();
    let obj = v.as_object().unwrap();
    let mut keys: Vec<&str> = obj.keys().map(String::as_str).collect();
    keys.sort_unstable();
    assert_eq!(
        keys,
        [
            "counters",
            "di",
            "do",
            "id",
            "latched_high",
            "latched_low",
            "name",
            "power_on_value",
            "protocol",
            "safe_value",
            "watchdog"
        ]
    );
    assert_eq!(
        v,
        serde_json::json!({
            "id": 7,
            "protocol": "modbus",
            "do": 0x36,
            "di": 0x20,
            "counters": [3, 0, 0, 0, 0, 1, 0, 0],
            "latched_low": 0x21,
            "latched_high": 0x01,
            "safe_value": 0x14,
            "power_on_value": 0x08,
            "name": "RIG1",
            "watchdog": {"enabled": true, "timeout_ms": 1500, "expired": false}
        })
    );

    clock.advance(ms(1500));
    let v = serde_json::to_value(m.state()).unwrap();
    assert_eq!(v["do"], 0x14);
    assert_eq!(
        v["watchdog"],
        serde_json::json!({"enabled": true, "timeout_ms": 1500, "expired": true})
    );

    let (mut a, _) = ascii();
    let v = serde_json::to_value(a.state()).unwrap();
    assert_eq!(v["protocol"], "ascii");
    assert_eq!(
        v["watchdog"],
        serde_json::json!({"enabled": false, "timeout_ms": 0, "expired": false})
    );
    let back: SimState = serde_json::from_value(v).unwrap();
    assert_eq!(back, a.state());
}

// ---- EEPROM and the state file ---------------------------------------------------------------

#[test]
fn eeprom_survives_power_cycle_in_memory() {
    let (mut m, _) = ascii();
    m.set_name("KEEP").unwrap();
    m.set_safe_value(0x11).unwrap();
    m.set_power_on_value(0x22).unwrap();
    m.set_watchdog(30).unwrap();
    m.set_led_mode(1).unwrap();
    m.pulse(1, 9).unwrap();
    m.save_counters().unwrap();
    let before = m.eeprom().clone();
    m.power_cycle();
    assert_eq!(m.eeprom(), &before);
    assert_eq!(m.counter(1), Ok(9));
    assert_eq!(m.outputs(), 0x22);
}

#[test]
fn eeprom_json_round_trips() {
    let mut e = Eeprom::factory();
    e.name = "AB CD".into();
    e.saved_counters = [1, 2, 3, 4, 5, 6, 7, 65_535];
    e.config.counter_edge = CounterEdge::Falling;
    e.watchdog_tenths = 0xFF;
    e.safe_mode = true;
    let text = serde_json::to_string(&e).unwrap();
    assert_eq!(Eeprom::from_json(&text), Ok(e));
}

#[test]
fn state_file_is_created_and_persists_across_instances() {
    let dir = TempDir::new("persist");
    let path = dir.file("io.json");
    let clock = VirtualClock::at_epoch();
    let shared: SharedClock = Arc::new(clock.clone());
    {
        let mut m =
            C29uModel::with_state_file(Protocol::Ascii, shared.clone(), path.clone()).unwrap();
        assert!(path.exists(), "factory image written at once");
        assert_eq!(m.eeprom(), &Eeprom::factory());
        assert_eq!(m.state_file(), Some(path.as_path()));
        m.set_name("SAVED").unwrap();
        m.write_outputs(0x3C).unwrap();
        m.save_outputs_as_power_on().unwrap();
        m.pulse(7, 42).unwrap();
        m.save_counters().unwrap();
        m.pulse(7, 1).unwrap(); // not saved
        m.set_watchdog(100).unwrap();
        assert_eq!(Eeprom::load(&path).unwrap(), *m.eeprom());
    }
    let mut m = C29uModel::with_state_file(Protocol::Ascii, shared, path.clone()).unwrap();
    assert_eq!(m.name(), "SAVED");
    assert_eq!(m.outputs(), 0x3C);
    assert_eq!(m.counter(7), Ok(42));
    assert_eq!(m.watchdog().timeout_tenths, 100);
    assert!(m.take_reset_flag());
    let leftovers: Vec<_> = std::fs::read_dir(&dir.0)
        .unwrap()
        .map(|e| e.unwrap().file_name())
        .collect();
    assert_eq!(leftovers.len(), 1, "no temp files left: {leftovers:?}");
}

#[test]
fn safe_mode_is_written_to_the_state_file() {
    let dir = TempDir::new("safe");
    let path = dir.file("io.json");
    let clock = VirtualClock::at_epoch();
    let shared: SharedClock = Arc::new(clock.clone());
    let mut m = C29uModel::with_state_file(Protocol::Modbus, shared.clone(), path.clone()).unwrap();
    m.set_safe_value(0x81).unwrap();
    m.set_watchdog(1).unwrap();
    clock.advance(ms(100));
    assert!(m.in_safe_mode());
    assert!(Eeprom::load(&path).unwrap().safe_mode);
    drop(m);
    let mut again = C29uModel::with_state_file(Protocol::Modbus, shared, path.clone()).unwrap();
    assert!(again.in_safe_mode());
    assert_eq!(again.outputs(), 0x81);
    again.set_watchdog(0).unwrap();
    assert!(!Eeprom::load(&path).unwrap().safe_mode);
}

#[test]
fn corrupt_state_file_is_a_typed_error_naming_the_file() {
    let dir = TempDir::new("corrupt");
    let clock: SharedClock = Arc::new(VirtualClock::at_epoch());
    let cases = [
        ("garbage.json", "{ not json".to_owned()),
        ("empty.json", String::new()),
        ("wrongtype.json", "[1,2,3]".to_owned()),
        (
            "badname.json",
            serde_json::to_string(&Eeprom {
                name: "TOO LONG NAME".into(),
                ..Eeprom::factory()
            })
            .unwrap(),
        ),
        (
            "badbaud.json",
            serde_json::to_string(&Eeprom {
                config: ModuleConfig {
                    baud_code: 0x42,
                    ..ModuleConfig::factory()
                },
                ..Eeprom::factory()
            })
            .unwrap(),
        ),
    ];
    for (file, text) in cases {
        let path = dir.file(file);
        std::fs::write(&path, text).unwrap();
        match C29uModel::with_state_file(Protocol::Ascii, clock.clone(), path.clone()) {
            Err(C29uModelError::Io(msg)) => assert!(msg.contains(file), "{msg}"),
            other => panic!("{file}: expected Io error, got {other:?}"),
        }
        match Eeprom::load(&path) {
            Err(C29uModelError::Io(msg)) => assert!(msg.contains(file), "{msg}"),
            other => panic!("{file}: expected Io error, got {other:?}"),
        }
    }
}

#[test]
fn unreadable_or_unwritable_state_file_is_an_io_error() {
    let dir = TempDir::new("unwritable");
    let clock: SharedClock = Arc::new(VirtualClock::at_epoch());
    // A directory where the file should be: cannot be read as a file.
    let path = dir.file("adir");
    std::fs::create_dir(&path).unwrap();
    assert!(matches!(
        C29uModel::with_state_file(Protocol::Ascii, clock.clone(), path),
        Err(C29uModelError::Io(_))
    ));
    // A missing parent directory: the factory image cannot be written.
    let path = dir.file("missing/io.json");
    match C29uModel::with_state_file(Protocol::Ascii, clock, path) {
        Err(C29uModelError::Io(msg)) => assert!(msg.contains("io.json"), "{msg}"),
        other => panic!("expected Io error, got {other:?}"),
    }
}

#[test]
fn a_failed_eeprom_write_changes_nothing() {
    let dir = TempDir::new("failwrite");
    let path = dir.file("io.json");
    let clock: SharedClock = Arc::new(VirtualClock::at_epoch());
    let mut m = C29uModel::with_state_file(Protocol::Ascii, clock, path).unwrap();
    std::fs::remove_dir_all(&dir.0).unwrap(); // the directory vanishes under the module
    assert!(matches!(m.set_name("NEW"), Err(C29uModelError::Io(_))));
    assert_eq!(m.name(), "TRPC29");
    assert!(matches!(m.set_watchdog(5), Err(C29uModelError::Io(_))));
    assert!(!m.watchdog().enabled);
}

// ---- documented boundaries and manual examples ---------------------------------------------

#[test]
fn the_watchdog_fires_when_a_whole_timeout_has_passed() {
    // Reading: fires once elapsed >= timeout, so a Host OK exactly at the deadline is too late.
    let (mut m, clock) = ascii();
    m.set_watchdog(3).unwrap();
    clock.advance(ms(299));
    m.host_ok();
    assert!(!m.in_safe_mode());
    clock.advance(ms(300));
    m.host_ok();
    assert!(m.in_safe_mode());
}

#[test]
fn timeout_0f_is_1_5_s_not_the_1_6_s_of_8_21() {
    // 8-21 says "0F..1.6 Sec"; by 8-19's unit, 0x0F x 0.1 s = 1.5 s.
    let (mut m, clock) = ascii();
    m.set_watchdog(0x0F).unwrap();
    assert_eq!(m.state().watchdog.timeout_ms, 1500);
    clock.advance(ms(1500));
    assert!(m.in_safe_mode(), "fired at 1.5 s");
}

#[test]
fn safe_mode_status_keeps_the_timeout_like_8_21() {
    // 8-21 "!01WD0F": D = "disable or safe mode" with timeout 0F. The model reports the
    // fired watchdog as enabled + expired with its timeout; the front end chooses the letter.
    let (mut m, clock) = ascii();
    m.set_watchdog(0x0F).unwrap();
    clock.advance(ms(2000));
    assert_eq!(
        m.watchdog(),
        WatchdogStatus {
            enabled: true,
            timeout_tenths: 0x0F,
            expired: true
        }
    );
}

#[test]
fn modbus_10_9_example_watchdog_reads_enabled_0f() {
    // 10-9 as read: "01 46 0C 01 0F" = enabled, 1.5 s.
    let (mut m, _) = module(Protocol::Modbus);
    m.set_watchdog(0x0F).unwrap();
    let wd = m.watchdog();
    assert_eq!((wd.enabled, wd.timeout_tenths), (true, 0x0F));
}

#[test]
fn modbus_10_14_safe_value_reads_back() {
    // 10-13 / 10-14: set safe value 14, read it back.
    let (mut m, _) = module(Protocol::Modbus);
    m.set_safe_value(0x14).unwrap();
    assert_eq!(m.safe_value(), 0x14);
}

#[test]
fn modbus_10_19_counter_example_values() {
    // 10-19: channels 0..3 read 0x28, 0x5A, 0x53, 0x55.
    let (mut m, _) = module(Protocol::Modbus);
    for (ch, n) in [(0u8, 0x28u32), (1, 0x5A), (2, 0x53), (3, 0x55)] {
        m.pulse(ch, n).unwrap();
    }
    assert_eq!(m.counters(), [0x28, 0x5A, 0x53, 0x55, 0, 0, 0, 0]);
}

#[test]
fn modbus_10_17_do_example_36_is_ch1_2_4_5() {
    let (mut m, _) = module(Protocol::Modbus);
    for ch in [1u8, 2, 4, 5] {
        m.write_output(ch, true).unwrap();
    }
    assert_eq!(m.outputs(), 0x36);
}

#[test]
fn changing_the_counter_edge_keeps_the_counts() {
    let (mut m, _) = ascii();
    m.pulse(0, 10).unwrap();
    let mut cfg = m.config();
    cfg.counter_edge = CounterEdge::Falling;
    m.set_config(cfg).unwrap();
    assert_eq!(m.counter(0), Ok(10));
}

// The model can move between threads: checked when this compiles (a test of it could not fail).
const _: fn() = || {
    fn is_send<T: Send>() {}
    is_send::<C29uModel>();
};

#[test]
fn flush_is_a_no_op_without_a_pending_write() {
    let (mut m, _) = ascii();
    assert_eq!(m.flush(), Ok(()));
}

// ---- properties -------------------------------------------------------------------------------

mod props {
    use super::*;
    use proptest::prelude::*;

    fn edge() -> impl Strategy<Value = CounterEdge> {
        prop_oneof![Just(CounterEdge::Rising), Just(CounterEdge::Falling)]
    }

    fn valid_config() -> impl Strategy<Value = ModuleConfig> {
        (
            any::<u8>(),
            3u8..=0x0A,
            any::<bool>(),
            edge(),
            any::<bool>(),
        )
            .prop_map(|(id, baud_code, checksum, counter_edge, hex_counters)| {
                ModuleConfig {
                    id,
                    baud_code,
                    checksum,
                    counter_edge,
                    hex_counters,
                }
            })
    }

    fn valid_eeprom() -> impl Strategy<Value = Eeprom> {
        (
            valid_config(),
            "[ -~]{1,6}",
            any::<[u16; 8]>(),
            any::<(u8, u8, u8)>(),
            0u8..=1,
            any::<bool>(),
        )
            .prop_map(
                |(config, name, saved_counters, (safe_value, power_on_value, wd), led, sm)| {
                    Eeprom {
                        config,
                        name,
                        saved_counters,
                        safe_value,
                        power_on_value,
                        watchdog_tenths: wd,
                        led_mode: led,
                        safe_mode: sm,
                    }
                },
            )
    }

    /// Field-side steps, for the counter reference model.
    #[derive(Debug, Clone)]
    enum Field {
        Inputs(u8),
        Pulse(u8, u32),
        Edge(CounterEdge),
    }

    fn field() -> impl Strategy<Value = Field> {
        prop_oneof![
            4 => any::<u8>().prop_map(Field::Inputs),
            2 => (0u8..8, prop_oneof![0u32..5, any::<u32>()]).prop_map(|(c, n)| Field::Pulse(c, n)),
            1 => edge().prop_map(Field::Edge),
        ]
    }

    /// Any step a host or operator can take, channels and values unrestricted.
    #[derive(Debug, Clone)]
    enum Op {
        Inputs(u8),
        Pulse(u8, u32),
        Advance(u16),
        HostOk,
        Watchdog(u8),
        Write(u8),
        WriteBit(u8, bool),
        Reset,
        PowerCycle,
        ClearLatches,
        ClearCounter(u8),
        ClearCounters,
        SaveCounters,
        Safe(u8),
        PowerOn(u8),
        SaveSafe,
        SaveOn,
        Synchronize,
        ReadSynchronized,
        Name(String),
        Led(u8),
        Config(u8, u8, u8),
        TakeReset,
    }

    fn op() -> impl Strategy<Value = Op> {
        prop_oneof![
            any::<u8>().prop_map(Op::Inputs),
            (any::<u8>(), any::<u32>()).prop_map(|(c, n)| Op::Pulse(c, n)),
            any::<u16>().prop_map(Op::Advance),
            Just(Op::HostOk),
            prop_oneof![Just(0u8), 1u8..4, any::<u8>()].prop_map(Op::Watchdog),
            any::<u8>().prop_map(Op::Write),
            (any::<u8>(), any::<bool>()).prop_map(|(c, b)| Op::WriteBit(c, b)),
            Just(Op::Reset),
            Just(Op::PowerCycle),
            Just(Op::ClearLatches),
            any::<u8>().prop_map(Op::ClearCounter),
            Just(Op::ClearCounters),
            Just(Op::SaveCounters),
            any::<u8>().prop_map(Op::Safe),
            any::<u8>().prop_map(Op::PowerOn),
            Just(Op::SaveSafe),
            Just(Op::SaveOn),
            Just(Op::Synchronize),
            Just(Op::ReadSynchronized),
            ".{0,8}".prop_map(Op::Name),
            any::<u8>().prop_map(Op::Led),
            any::<(u8, u8, u8)>().prop_map(|(a, b, c)| Op::Config(a, b, c)),
            Just(Op::TakeReset),
        ]
    }

    fn apply(m: &mut C29uModel, clock: &VirtualClock, op: &Op) {
        match *op {
            Op::Inputs(v) => m.set_inputs(v),
            Op::Pulse(c, n) => {
                let _ = m.pulse(c, n);
            }
            Op::Advance(d) => clock.advance(ms(u64::from(d))),
            Op::HostOk => m.host_ok(),
            Op::Watchdog(t) => m.set_watchdog(t).unwrap(),
            Op::Write(v) => {
                let _ = m.write_outputs(v);
            }
            Op::WriteBit(c, b) => {
                let _ = m.write_output(c, b);
            }
            Op::Reset => m.reset(),
            Op::PowerCycle => m.power_cycle(),
            Op::ClearLatches => m.clear_latches(),
            Op::ClearCounter(c) => {
                let _ = m.clear_counter(c);
            }
            Op::ClearCounters => m.clear_counters(),
            Op::SaveCounters => m.save_counters().unwrap(),
            Op::Safe(v) => m.set_safe_value(v).unwrap(),
            Op::PowerOn(v) => m.set_power_on_value(v).unwrap(),
            Op::SaveSafe => m.save_outputs_as_safe().unwrap(),
            Op::SaveOn => m.save_outputs_as_power_on().unwrap(),
            Op::Synchronize => m.synchronize(),
            Op::ReadSynchronized => {
                let _ = m.read_synchronized();
            }
            Op::Name(ref n) => {
                let _ = m.set_name(n);
            }
            Op::Led(v) => {
                let _ = m.set_led_mode(v);
            }
            Op::Config(id, baud, dd) => {
                let parsed = DataFormat::from_byte(dd)
                    .and_then(|f| ModuleConfig::from_parts(id, baud, f).ok());
                if let Some(cfg) = parsed {
                    let _ = m.set_config(cfg);
                }
            }
            Op::TakeReset => {
                let _ = m.take_reset_flag();
            }
        }
    }

    proptest! {
        #[test]
        fn data_format_round_trips(cfg in valid_config()) {
            let back = ModuleConfig::from_parts(cfg.id, cfg.baud_code, cfg.data_format());
            prop_assert_eq!(back, Ok(cfg));
            let report = cfg.report();
            prop_assert_eq!(report.model(), ConfigReport::MODEL_C29U);
            prop_assert_eq!(report.format & 0xC0, cfg.data_format().to_byte() & 0xC0);
        }

        #[test]
        fn from_parts_never_panics_and_accepts_only_valid(id: u8, baud: u8, dd: u8) {
            let ok = DataFormat::from_byte(dd)
                .is_some_and(|f| ModuleConfig::from_parts(id, baud, f).is_ok());
            prop_assert_eq!(ok, (3..=0x0A).contains(&baud) && dd & 0x3E == 0);
        }

        #[test]
        fn eeprom_json_round_trips_for_any_valid_image(e in valid_eeprom()) {
            let text = serde_json::to_string(&e).unwrap();
            prop_assert_eq!(Eeprom::from_json(&text), Ok(e));
        }

        #[test]
        fn eeprom_parser_never_panics_on_random_text(text in ".{0,200}") {
            let _ = Eeprom::from_json(&text);
        }

        #[test]
        fn eeprom_parser_never_panics_on_random_bytes(bytes in proptest::collection::vec(any::<u8>(), 0..200)) {
            let _ = Eeprom::from_json(&String::from_utf8_lossy(&bytes));
        }

        #[test]
        fn state_round_trips_through_json(e in valid_eeprom(), inputs: u8) {
            let clock = VirtualClock::at_epoch();
            let mut m = C29uModel::new(Protocol::Ascii, Arc::new(clock), e);
            m.set_inputs(inputs);
            let s = m.state();
            let back: SimState = serde_json::from_str(&serde_json::to_string(&s).unwrap()).unwrap();
            prop_assert_eq!(back, s);
        }

        /// Counters and latches agree with an independent edge count, modulo 2^16.
        #[test]
        fn counters_and_latches_match_a_reference(steps in proptest::collection::vec(field(), 0..60)) {
            let (mut m, _) = ascii();
            let mut level = 0u8;
            let mut edge = CounterEdge::Rising;
            let mut counts = [0u64; 8];
            let (mut low, mut high) = (0u8, 0u8);
            for step in &steps {
                match *step {
                    Field::Inputs(v) => {
                        for (ch, count) in counts.iter_mut().enumerate() {
                            let was = level >> ch & 1 == 1;
                            let now = v >> ch & 1 == 1;
                            if !was && now { low |= 1 << ch; }
                            if was && !now { high |= 1 << ch; }
                            let counted = match edge {
                                CounterEdge::Rising => !was && now,
                                CounterEdge::Falling => was && !now,
                            };
                            if counted { *count += 1; }
                        }
                        level = v;
                        m.set_inputs(v);
                    }
                    Field::Pulse(ch, n) => {
                        if n > 0 {
                            low |= 1 << ch;
                            high |= 1 << ch;
                        }
                        counts[usize::from(ch)] += u64::from(n);
                        m.pulse(ch, n).unwrap();
                    }
                    Field::Edge(e) => {
                        edge = e;
                        let mut cfg = m.config();
                        cfg.counter_edge = e;
                        m.set_config(cfg).unwrap();
                    }
                }
            }
            let expected: Vec<u16> = counts.iter().map(|c| (c % 65_536) as u16).collect();
            prop_assert_eq!(m.counters().to_vec(), expected);
            prop_assert_eq!(m.latched_low(), low);
            prop_assert_eq!(m.latched_high(), high);
            prop_assert_eq!(m.inputs(), level);
        }

        /// The watchdog fires exactly when some gap between Host OKs reached the timeout.
        #[test]
        fn watchdog_matches_a_reference(
            t in 1u8..=255,
            steps in proptest::collection::vec(prop_oneof![
                (0u64..3000).prop_map(Some),
                Just(None),
            ], 0..40),
        ) {
            let (mut m, clock) = ascii();
            m.set_safe_value(0xA5).unwrap();
            m.write_outputs(0x5A).unwrap();
            m.set_watchdog(t).unwrap();
            let timeout = u64::from(t) * 100;
            let (mut now, mut kicked, mut fired) = (0u64, 0u64, false);
            for step in &steps {
                match *step {
                    Some(d) => { now += d; clock.advance(ms(d)); }
                    None => {
                        if now - kicked >= timeout { fired = true; } else if !fired { kicked = now; }
                        m.host_ok();
                    }
                }
            }
            if now - kicked >= timeout { fired = true; }
            prop_assert_eq!(m.in_safe_mode(), fired);
            prop_assert_eq!(m.outputs(), if fired { 0xA5 } else { 0x5A });
            prop_assert_eq!(m.write_outputs(0).is_err(), fired);
        }

        /// Whatever is done, nothing panics and the module's invariants hold.
        #[test]
        fn any_sequence_keeps_the_invariants(steps in proptest::collection::vec(op(), 0..50)) {
            let (mut m, clock) = ascii();
            for step in &steps {
                apply(&mut m, &clock, step);
                prop_assert_eq!(m.inputs_wire(), !m.inputs());
                let wd = m.watchdog();
                prop_assert!(!wd.expired || wd.enabled, "safe mode only with a watchdog set");
                prop_assert_eq!(wd.enabled, wd.timeout_tenths != 0);
                if wd.expired {
                    let before = m.outputs();
                    prop_assert_eq!(m.write_outputs(!before), Err(C29uModelError::SafeMode));
                    prop_assert_eq!(m.outputs(), before);
                }
                prop_assert!(m.eeprom().validate().is_ok());
                prop_assert!(!m.name().is_empty() && m.name().len() <= 6);
                for ch in 8..=255u8 {
                    prop_assert_eq!(m.counter(ch), Err(C29uModelError::BadChannel(ch)));
                }
            }
        }
    }
}

#[test]
fn a_failed_write_when_the_watchdog_fires_is_retried_by_flush() {
    let dir = TempDir::new("flush");
    let path = dir.file("io.json");
    let clock = VirtualClock::at_epoch();
    let mut m =
        C29uModel::with_state_file(Protocol::Ascii, Arc::new(clock.clone()), path.clone()).unwrap();
    m.set_watchdog(1).unwrap();
    std::fs::remove_dir_all(&dir.0).unwrap();
    clock.advance(ms(100));
    assert!(
        m.in_safe_mode(),
        "fires even though the file cannot be written"
    );
    assert!(matches!(m.flush(), Err(C29uModelError::Io(_))));
    std::fs::create_dir_all(&dir.0).unwrap();
    m.flush().unwrap();
    assert!(Eeprom::load(&path).unwrap().safe_mode);
}

// ---- faulty output stage, swap -----------------------------------------------------------

#[test]
fn an_output_stage_that_ignores_writes_acknowledges_them_and_keeps_its_outputs() {
    let (mut m, clock) = module(Protocol::Modbus);
    m.write_outputs(0x1F).unwrap();
    m.set_output_fault(Some(OutputFault::Ignore));
    assert_eq!(m.write_outputs(0x05), Ok(()));
    assert_eq!(m.write_output(7, true), Ok(()));
    assert_eq!(m.outputs(), 0x1F);
    // Its watchdog still acts on the outputs.
    m.set_safe_value(0x05).unwrap();
    m.set_watchdog(1).unwrap();
    clock.advance(ms(100));
    assert_eq!(m.outputs(), 0x05);
    m.set_output_fault(None);
    m.set_watchdog(0).unwrap();
    m.write_outputs(0x21).unwrap();
    assert_eq!(m.outputs(), 0x21);
}

#[test]
fn a_refusing_output_stage_answers_with_its_exception_code() {
    use crate::protocol::c29u_modbus::{parse_response, ModbusError, Request};
    let (mut m, _) = module(Protocol::Modbus);
    for code in [0x04u8, 0xFF] {
        m.set_output_fault(Some(OutputFault::Refuse(code)));
        let request = Request::write_outputs(0x05);
        let answer = crate::sim::c29u_modbus::answer(&mut m, &request.encode(1)).unwrap();
        let decoded = parse_response(&request, 1, &answer);
        match code {
            0xFF => assert!(
                matches!(decoded, Err(ModbusError::SafeMode { .. })),
                "{decoded:?}"
            ),
            _ => assert!(
                matches!(decoded, Err(ModbusError::Exception { .. })),
                "{decoded:?}"
            ),
        }
        assert_eq!(m.outputs(), 0x00);
    }
}

#[test]
fn a_swapped_module_keeps_the_line_settings_and_brings_its_own_name_firmware_and_values() {
    let (mut m, _) = ascii();
    m.set_safe_value(0x05).unwrap();
    m.set_watchdog(10).unwrap();
    m.take_reset_flag();
    let mut other = Eeprom::factory();
    "OTHER".clone_into(&mut other.name);
    other.safe_value = 0xFF;
    other.power_on_value = 0x9C;
    let firmware = crate::protocol::c29u::FirmwareDate {
        year: 14,
        month: 9,
        day: 1,
    };
    m.swap(other, firmware).unwrap();
    assert_eq!(
        m.config(),
        ModuleConfig::factory(),
        "same ID and line settings"
    );
    assert_eq!(m.name(), "OTHER");
    assert_eq!(m.firmware(), firmware);
    assert_eq!(m.safe_value(), 0xFF);
    assert!(!m.watchdog().enabled);
    assert_eq!(m.outputs(), 0x9C, "powered on");
    assert!(m.take_reset_flag());
}
