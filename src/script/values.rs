//! Rhai values to JSON (records) and back (scenario tests read records).

use rhai::{Array, Dynamic, Map};
use serde_json::{Number, Value};

/// A script value as JSON: numbers, strings, booleans, arrays and maps as themselves, `()` as
/// null, anything else (a device handle, a function pointer) as its text.
pub fn to_json(v: &Dynamic) -> Value {
    if v.is_unit() {
        Value::Null
    } else if let Some(b) = v.clone().try_cast::<bool>() {
        Value::Bool(b)
    } else if let Some(i) = v.clone().try_cast::<i64>() {
        Value::Number(i.into())
    } else if let Some(f) = v.clone().try_cast::<f64>() {
        Number::from_f64(f).map_or(Value::Null, Value::Number)
    } else if v.is_string() {
        Value::String(v.to_string())
    } else if let Some(c) = v.clone().try_cast::<char>() {
        Value::String(c.to_string())
    } else if let Some(a) = v.clone().try_cast::<Array>() {
        Value::Array(a.iter().map(to_json).collect())
    } else if let Some(m) = v.clone().try_cast::<Map>() {
        Value::Object(m.iter().map(|(k, v)| (k.to_string(), to_json(v))).collect())
    } else {
        Value::String(v.to_string())
    }
}

/// JSON as a script value (null as `()`, whole numbers as integers).
pub fn from_json(v: &Value) -> Dynamic {
    match v {
        Value::Null => Dynamic::UNIT,
        Value::Bool(b) => Dynamic::from(*b),
        Value::Number(n) => match n.as_i64() {
            Some(i) => Dynamic::from(i),
            None => Dynamic::from(n.as_f64().unwrap_or(f64::NAN)),
        },
        Value::String(s) => Dynamic::from(s.clone()),
        Value::Array(a) => Dynamic::from_array(a.iter().map(from_json).collect()),
        Value::Object(o) => {
            let m: Map = o
                .iter()
                .map(|(k, v)| (k.as_str().into(), from_json(v)))
                .collect();
            Dynamic::from_map(m)
        }
    }
}

/// A script value for messages: strings quoted, the rest as JSON.
pub fn show(v: &Dynamic) -> String {
    to_json(v).to_string()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn values_round_trip_through_json() {
        let e = rhai::Engine::new();
        let v: Dynamic = e
            .eval(r#"#{a: 1, b: [true, "x", 1.5, ()], c: #{d: -2}}"#)
            .unwrap();
        let j = to_json(&v);
        assert_eq!(
            j,
            json!({"a": 1, "b": [true, "x", 1.5, null], "c": {"d": -2}})
        );
        assert_eq!(to_json(&from_json(&j)), j);
        assert_eq!(show(&Dynamic::from("hi".to_string())), "\"hi\"");
    }
}
