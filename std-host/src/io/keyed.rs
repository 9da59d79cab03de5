//! A JSON object whose keys are only known at run time (stage labels, readout names), written
//! in their order: a `serde_json::Map` sorts its keys, and its `preserve_order` feature would
//! change every map in the workspace.

use serde::{Serialize, Serializer};

/// `(key, value)` pairs serialised as one object, in order.
#[derive(Debug, Clone, PartialEq)]
pub struct Keyed<V>(pub Vec<(String, V)>);

impl<V: Serialize> Serialize for Keyed<V> {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        s.collect_map(self.0.iter().map(|(k, v)| (k, v)))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_the_keys_in_their_order() {
        let k = Keyed(vec![("b".to_string(), 1.5), ("a".to_string(), f64::NAN)]);
        assert_eq!(serde_json::to_string(&k).unwrap(), r#"{"b":1.5,"a":null}"#);
    }
}
