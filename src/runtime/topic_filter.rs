//! MQTT topic names and filters as the script and the broker client check them (pure):
//! `+` stands for one level, `#` for the rest.

/// The longest topic the rig publishes to or accepts (MQTT allows 64 KiB; nobody needs that).
pub const MAX_TOPIC: usize = 512;

/// The largest payload handed on either way (a command's, a watched topic's, a script's
/// `mqtt_publish`); an inbound one larger is dropped, counted, and a command gets an error reply.
pub const MAX_PAYLOAD: usize = 64 << 10;

/// Whether an MQTT topic filter (`+` one level, `#` the rest) matches `topic`.
pub fn filter_matches(filter: &str, topic: &str) -> bool {
    let mut f = filter.split('/');
    let mut t = topic.split('/');
    loop {
        match (f.next(), t.next()) {
            (Some("#"), _) => return true,
            (Some("+"), Some(_)) => {}
            (Some(a), Some(b)) if a == b => {}
            (None, None) => return true,
            _ => return false,
        }
    }
}

/// Whether `filter` is a topic filter a script may watch: levels, `+` alone in a level, `#`
/// alone in the last.
pub fn check_filter(filter: &str) -> Result<(), String> {
    let levels: Vec<&str> = filter.split('/').collect();
    let last = levels.len() - 1;
    let ok = !filter.is_empty()
        && filter.len() <= MAX_TOPIC
        && !filter.contains('\0')
        && levels.iter().enumerate().all(|(n, l)| match *l {
            "#" => n == last,
            "+" => true,
            l => !l.contains(['#', '+']),
        });
    if ok {
        Ok(())
    } else {
        Err(format!(
            "{filter:?} is not a topic filter: levels split by '/', '+' alone for one level, \
             '#' alone at the end for the rest, at most {MAX_TOPIC} bytes"
        ))
    }
}

/// Whether `topic` can be published to: no wildcards, not empty, bounded.
pub fn check_topic(topic: &str) -> Result<(), String> {
    if topic.is_empty() || topic.len() > MAX_TOPIC || topic.contains(['#', '+', '\0']) {
        return Err(format!(
            "{topic:?} is not a topic to publish to: 1-{MAX_TOPIC} bytes without '#' or '+'"
        ));
    }
    Ok(())
}
