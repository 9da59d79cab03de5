//! Just enough JSON writing for the CLI's reports (`bino compare --json`, `bino bench --json`):
//! the crate has no serde, and the reports are flat objects of numbers and strings.

use std::fmt::Write;

/// `s` as a JSON string literal.
pub fn string(s: &str) -> String {
    let mut out = String::with_capacity(s.len() + 2);
    out.push('"');
    for c in s.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            '\r' => out.push_str("\\r"),
            '\t' => out.push_str("\\t"),
            c if (c as u32) < 0x20 => {
                let _ = write!(out, "\\u{:04x}", c as u32);
            }
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// `v` as a JSON number; `null` when it is not finite (JSON has no NaN or infinity).
pub fn number(v: f64) -> String {
    if v.is_finite() {
        format!("{v}")
    } else {
        "null".to_string()
    }
}

/// A JSON array of already-rendered values.
pub fn array(items: impl IntoIterator<Item = String>) -> String {
    format!("[{}]", items.into_iter().collect::<Vec<_>>().join(", "))
}

/// A JSON object built field by field, in insertion order.
#[derive(Debug, Clone, Default)]
pub struct Object {
    fields: Vec<(String, String)>,
}

impl Object {
    /// An empty object.
    pub fn new() -> Self {
        Self::default()
    }

    /// Adds `key` with an already-rendered JSON value.
    pub fn raw(mut self, key: &str, value: String) -> Self {
        self.fields.push((key.to_string(), value));
        self
    }

    /// Adds a string field.
    pub fn str(self, key: &str, value: &str) -> Self {
        self.raw(key, string(value))
    }

    /// Adds a number field (`null` when not finite).
    pub fn num(self, key: &str, value: f64) -> Self {
        self.raw(key, number(value))
    }

    /// Adds an integer field.
    pub fn int(self, key: &str, value: u64) -> Self {
        self.raw(key, value.to_string())
    }

    /// Adds a boolean field.
    pub fn bool(self, key: &str, value: bool) -> Self {
        self.raw(key, value.to_string())
    }

    /// The object's text.
    pub fn render(&self) -> String {
        let fields: Vec<String> = self.fields.iter().map(|(k, v)| format!("{}: {v}", string(k))).collect();
        format!("{{{}}}", fields.join(", "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strings_are_escaped() {
        assert_eq!(string("a\"b\\c\nd\u{1}"), r#""a\"b\\c\nd\u0001""#);
    }

    #[test]
    fn non_finite_numbers_are_null() {
        assert_eq!(number(1.5), "1.5");
        assert_eq!(number(f64::NAN), "null");
        assert_eq!(number(f64::NEG_INFINITY), "null");
    }

    #[test]
    fn objects_keep_field_order() {
        let o = Object::new()
            .str("name", "x")
            .num("v", 2.0)
            .int("n", 3)
            .bool("ok", true)
            .raw("list", array(["1".to_string(), "null".to_string()]));
        assert_eq!(
            o.render(),
            r#"{"name": "x", "v": 2, "n": 3, "ok": true, "list": [1, null]}"#
        );
    }
}
