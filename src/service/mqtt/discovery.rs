//! Home Assistant's MQTT discovery (`ha_discovery = true`): a config for each module input (a
//! binary sensor), counter (a sensor) and output (a binary sensor: read-only, a command
//! handler in the script is the only way in), and each panel's relay (a sensor), all reading
//! the rig's retained state topics and going unavailable with its status.

use super::topics::{Topics, OFFLINE, ONLINE};
use crate::runtime::snapshot::{DeviceState, RigSnapshot};
use serde_json::{json, Value};

/// Discovery configs as (topic, retained payload), under Home Assistant's default prefix.
pub fn configs(rig: &str, topics: &Topics, snapshot: &RigSnapshot) -> Vec<(String, String)> {
    let node = object_id(rig);
    let device = json!({"identifiers": [format!("rigscript-{rig}")], "name": rig,
                        "manufacturer": "rigscript", "model": "rig"});
    let mut out = Vec::new();
    let mut add =
        |component: &str, object: String, name: String, state: String, template: String| {
            let config = json!({
                "name": name,
                "unique_id": format!("rigscript_{node}_{object}"),
                "object_id": format!("{node}_{object}"),
                "state_topic": state,
                "value_template": template,
                "availability_topic": topics.status(),
                "payload_available": ONLINE,
                "payload_not_available": OFFLINE,
                "device": device,
            });
            out.push((
                format!("homeassistant/{component}/{node}/{object}/config"),
                Value::to_string(&config),
            ));
        };
    for (name, state) in &snapshot.devices {
        let obj = object_id(name);
        let topic = topics.state(name);
        match state {
            DeviceState::C29u { .. } => {
                for ch in 0..8 {
                    let bit = 1u32 << ch;
                    add(
                        "binary_sensor",
                        format!("{obj}_di{ch}"),
                        format!("{name} DI{ch}"),
                        topic.clone(),
                        format!(
                            "{{{{ 'ON' if (value_json.inputs | int(0)) | bitwise_and({bit}) \
                             else 'OFF' }}}}"
                        ),
                    );
                    add(
                        "binary_sensor",
                        format!("{obj}_do{ch}"),
                        format!("{name} DO{ch}"),
                        topic.clone(),
                        format!(
                            "{{{{ 'ON' if (value_json.outputs | int(0)) | bitwise_and({bit}) \
                             else 'OFF' }}}}"
                        ),
                    );
                    add(
                        "sensor",
                        format!("{obj}_counter{ch}"),
                        format!("{name} counter {ch}"),
                        topic.clone(),
                        format!("{{{{ (value_json.counters or [])[{ch}] | default(none) }}}}"),
                    );
                }
            }
            DeviceState::Trc { .. } => add(
                "sensor",
                format!("{obj}_relay"),
                format!("{name} relay"),
                topic.clone(),
                "{{ value_json.relay }}".into(),
            ),
        }
    }
    out
}

/// A name as Home Assistant's object ids take it: letters, digits and `_`.
fn object_id(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() {
                c.to_ascii_lowercase()
            } else {
                '_'
            }
        })
        .collect()
}
