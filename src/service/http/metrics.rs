//! `GET /metrics`: a run's snapshot in the Prometheus text format (version 0.0.4), for a
//! fleet's monitoring to scrape: ticks, overruns, jitter and work, transactions, each
//! device's online state, inputs, outputs and counters, the events consumers lost, and the
//! MQTT client's connection and losses.

use crate::runtime::snapshot::{Buckets, DeviceState, MqttState, RigSnapshot, BUCKET_BOUNDS_US};
use std::fmt::Write;

/// The media type of the text format.
pub const CONTENT_TYPE: &str = "text/plain; version=0.0.4; charset=utf-8";

/// The metrics of `s`.
pub fn render(s: &RigSnapshot) -> String {
    let mut out = Metrics(String::new());
    let t = &s.ticks;
    out.one("rigscript_ticks_total", "counter", "Ticks run.", t.count);
    out.one(
        "rigscript_overruns_total",
        "counter",
        "Ticks that ran past the next deadline.",
        t.overruns,
    );
    out.one(
        "rigscript_period_seconds",
        "gauge",
        "The scan period.",
        seconds(t.period_us),
    );
    out.one(
        "rigscript_jitter_p99_seconds",
        "gauge",
        "How late ticks started, 99th percentile.",
        seconds(t.jitter_p99_us),
    );
    out.one(
        "rigscript_tick_work_p99_seconds",
        "gauge",
        "Tick work, 99th percentile.",
        seconds(t.work_p99_us),
    );
    out.histogram(
        "rigscript_tick_work_seconds",
        "How long each tick's work took.",
        &t.work,
    );
    out.histogram(
        "rigscript_jitter_seconds",
        "How late each tick started after its deadline.",
        &t.jitter,
    );
    out.one(
        "rigscript_transactions_total",
        "counter",
        "Requests sent to devices.",
        t.transactions,
    );
    out.one(
        "rigscript_script_errors_total",
        "counter",
        "Script errors.",
        s.script.errors,
    );
    out.one(
        "rigscript_script_restarts_total",
        "counter",
        "Times the script was started again.",
        s.script.restarts,
    );
    out.one(
        "rigscript_held_safe",
        "gauge",
        "1 while every device is held at its safe state.",
        u8::from(s.held_safe),
    );
    out.one(
        "rigscript_forced_points",
        "gauge",
        "Points an operator forces now (rig.toml's force = true).",
        s.forces.len(),
    );
    out.one(
        "rigscript_log_dropped_total",
        "counter",
        "Log lines lost because the log was not read.",
        s.log_dropped,
    );
    out.one(
        "rigscript_records_lost_total",
        "counter",
        "Records the records file did not take (dropped or refused: a full disk).",
        s.records_lost,
    );
    out.family(
        "rigscript_events_dropped_total",
        "counter",
        "Events each consumer of the event stream lost.",
    );
    for d in &s.dropped {
        out.sample(
            "rigscript_events_dropped_total",
            &[("consumer", &d.consumer)],
            d.events,
        );
    }
    device_metrics(&mut out, s);
    if let Some(m) = &s.mqtt {
        mqtt_metrics(&mut out, m);
    }
    out.0
}

fn mqtt_metrics(out: &mut Metrics, m: &MqttState) {
    out.one(
        "rigscript_mqtt_connected",
        "gauge",
        "1 while the broker has accepted the MQTT client's connection.",
        u8::from(m.connected),
    );
    out.one(
        "rigscript_mqtt_failed",
        "gauge",
        "1 once the MQTT client has stopped for good (its thread panicked; status says why).",
        u8::from(m.failed.is_some()),
    );
    out.one(
        "rigscript_mqtt_connect_failures_total",
        "counter",
        "MQTT connections that failed or were refused.",
        m.connect_failures,
    );
    out.one(
        "rigscript_mqtt_outbox_waiting",
        "gauge",
        "Records in the MQTT outbox waiting for the broker.",
        m.outbox_waiting,
    );
    out.family(
        "rigscript_mqtt_dropped_total",
        "counter",
        "What the MQTT client lost, by kind (outbox_full, outbox_write, messages, commands, \
         publishes, log, refused, too_large, replies).",
    );
    for (kind, n) in m.dropped.by_kind() {
        out.sample("rigscript_mqtt_dropped_total", &[("kind", kind)], n);
    }
}

fn device_metrics(out: &mut Metrics, s: &RigSnapshot) {
    out.family(
        "rigscript_device_online",
        "gauge",
        "1 while the device answers.",
    );
    for (name, d) in &s.devices {
        out.sample(
            "rigscript_device_online",
            &[("device", name)],
            u8::from(d.online()),
        );
    }
    out.family(
        "rigscript_device_inputs",
        "gauge",
        "A TRP-C29U's DI byte as last read (bit n: DIn).",
    );
    for (name, d) in &s.devices {
        if let DeviceState::C29u {
            inputs: Some(v), ..
        } = d
        {
            out.sample("rigscript_device_inputs", &[("device", name)], *v);
        }
    }
    out.family(
        "rigscript_device_outputs",
        "gauge",
        "A TRP-C29U's DO byte as the script commands it.",
    );
    for (name, d) in &s.devices {
        if let DeviceState::C29u { outputs, .. } = d {
            out.sample("rigscript_device_outputs", &[("device", name)], *outputs);
        }
    }
    out.family(
        "rigscript_device_counter",
        "gauge",
        "A TRP-C29U's counters as last read.",
    );
    for (name, d) in &s.devices {
        if let DeviceState::C29u {
            counters: Some(c), ..
        } = d
        {
            for (channel, value) in c.iter().enumerate() {
                let channel = channel.to_string();
                out.sample(
                    "rigscript_device_counter",
                    &[("device", name), ("channel", &channel)],
                    *value,
                );
            }
        }
    }
    out.family(
        "rigscript_device_relay",
        "gauge",
        "A TRC1000's relay as the script commands it (0: none).",
    );
    for (name, d) in &s.devices {
        if let DeviceState::Trc { relay, .. } = d {
            out.sample("rigscript_device_relay", &[("device", name)], *relay);
        }
    }
}

fn seconds(us: u64) -> f64 {
    // Microseconds fit an f64 exactly far past any run's length.
    #[allow(clippy::cast_precision_loss)]
    let s = us as f64 / 1e6;
    s
}

struct Metrics(String);

impl Metrics {
    fn family(&mut self, name: &str, kind: &str, help: &str) {
        let _ = writeln!(self.0, "# HELP {name} {help}\n# TYPE {name} {kind}");
    }

    fn sample(&mut self, name: &str, labels: &[(&str, &str)], value: impl std::fmt::Display) {
        let labels: Vec<String> = labels
            .iter()
            .map(|(k, v)| format!("{k}=\"{}\"", escape(v)))
            .collect();
        if labels.is_empty() {
            let _ = writeln!(self.0, "{name} {value}");
        } else {
            let _ = writeln!(self.0, "{name}{{{}}} {value}", labels.join(","));
        }
    }

    /// A histogram family: `_bucket{le}` cumulative, `+Inf`, `_sum`, `_count`.
    fn histogram(&mut self, name: &str, help: &str, h: &Buckets) {
        self.family(name, "histogram", help);
        let bucket = format!("{name}_bucket");
        for (bound, count) in BUCKET_BOUNDS_US.iter().zip(&h.le) {
            let le = seconds(*bound).to_string();
            self.sample(&bucket, &[("le", &le)], count);
        }
        self.sample(&bucket, &[("le", "+Inf")], h.count);
        self.sample(&format!("{name}_sum"), &[], seconds(h.sum_us));
        self.sample(&format!("{name}_count"), &[], h.count);
    }

    fn one(&mut self, name: &str, kind: &str, help: &str, value: impl std::fmt::Display) {
        self.family(name, kind, help);
        self.sample(name, &[], value);
    }
}

/// A label value as the text format quotes it.
fn escape(v: &str) -> String {
    v.replace('\\', "\\\\")
        .replace('"', "\\\"")
        .replace('\n', "\\n")
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runtime::observe::Dropped;
    use crate::runtime::snapshot::{MqttDropped, ScriptState, TickFigures, SNAPSHOT_VERSION};
    use std::collections::BTreeMap;

    fn snapshot() -> RigSnapshot {
        let io = DeviceState::C29u {
            online: true,
            offline_reason: None,
            simulated: true,
            inputs: Some(5),
            outputs: 0x40,
            outputs_written: Some(0x40),
            counters: Some([1, 2, 3, 4, 5, 6, 7, 8]),
            latches: None,
            watchdog_ms: None,
            safe_value: 0,
            safe_mode: false,
            names: BTreeMap::new(),
            not_shown: Vec::new(),
        };
        let panel = DeviceState::Trc {
            online: false,
            offline_reason: Some("gone".into()),
            simulated: true,
            relay: 3,
            relay_written: None,
            pressed: None,
            rotaries: None,
            names: BTreeMap::new(),
            not_shown: Vec::new(),
        };
        RigSnapshot {
            version: SNAPSHOT_VERSION,
            script: ScriptState {
                file: "a.rhai".into(),
                state: "running".into(),
                uptime_ms: 1,
                ..ScriptState::default()
            },
            devices: BTreeMap::from([("io".into(), io), ("panel".into(), panel)]),
            held_safe: false,
            ticks: TickFigures {
                period_us: 20_000,
                count: 42,
                overruns: 1,
                jitter_p99_us: 1500,
                work_p99_us: 30,
                transactions: 9,
                work: Buckets {
                    le: vec![3, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5, 5],
                    count: 5,
                    sum_us: 400,
                },
                jitter: Buckets::default(),
                ..TickFigures::default()
            },
            dropped: vec![Dropped {
                consumer: "web \"x\"".into(),
                events: 7,
            }],
            log_dropped: 0,
            forcing: false,
            forces: Vec::new(),
            records_lost: 3,
            dropped_in_all: 7,
            mqtt: Some(MqttState {
                broker: "b:1883".into(),
                connected: true,
                connect_failures: 2,
                last_error: Some("refused".into()),
                failed: None,
                outbox_waiting: 4,
                dropped: MqttDropped {
                    messages: 5,
                    ..MqttDropped::default()
                },
            }),
        }
    }

    #[test]
    fn every_figure_and_device_is_a_sample_with_its_labels() {
        let text = render(&snapshot());
        for line in [
            "rigscript_ticks_total 42",
            "rigscript_overruns_total 1",
            "rigscript_period_seconds 0.02",
            "rigscript_jitter_p99_seconds 0.0015",
            "rigscript_device_online{device=\"io\"} 1",
            "rigscript_device_online{device=\"panel\"} 0",
            "rigscript_device_inputs{device=\"io\"} 5",
            "rigscript_device_outputs{device=\"io\"} 64",
            "rigscript_device_counter{device=\"io\",channel=\"7\"} 8",
            "rigscript_device_relay{device=\"panel\"} 3",
            "rigscript_events_dropped_total{consumer=\"web \\\"x\\\"\"} 7",
            "# TYPE rigscript_tick_work_seconds histogram",
            "rigscript_tick_work_seconds_bucket{le=\"0.00005\"} 3",
            "rigscript_tick_work_seconds_bucket{le=\"1\"} 5",
            "rigscript_tick_work_seconds_bucket{le=\"+Inf\"} 5",
            "rigscript_tick_work_seconds_sum 0.0004",
            "rigscript_tick_work_seconds_count 5",
            "rigscript_jitter_seconds_count 0",
            "rigscript_forced_points 0",
            "rigscript_records_lost_total 3",
            "rigscript_mqtt_dropped_total{kind=\"replies\"} 0",
            "rigscript_mqtt_connected 1",
            "rigscript_mqtt_failed 0",
            "rigscript_mqtt_connect_failures_total 2",
            "rigscript_mqtt_outbox_waiting 4",
            "rigscript_mqtt_dropped_total{kind=\"messages\"} 5",
            "rigscript_mqtt_dropped_total{kind=\"outbox_full\"} 0",
        ] {
            assert!(text.lines().any(|l| l == line), "no {line:?} in\n{text}");
        }
        // Every sample's family is declared once.
        let types = text.lines().filter(|l| l.starts_with("# TYPE")).count();
        let helps = text.lines().filter(|l| l.starts_with("# HELP")).count();
        assert_eq!(types, helps);
    }
}
