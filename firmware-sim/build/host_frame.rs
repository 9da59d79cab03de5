//! Reads `measured/host-frame-320x240.json` (`bino-host-frame/1`, written by `cargo test -p
//! bino-host --test e7_frame -- --ignored`) without a JSON crate: the build needs only each run's
//! preset, refined digest and arena, flat fields of the objects in its `runs` array.

/// One `bino run` of the E7 frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HostRun {
    /// `fast` or `learned`.
    pub preset: String,
    /// CRC-32 of its refined rows in Q8.
    pub refined: u32,
    /// The arena it reports, bytes.
    pub arena_bytes: usize,
    /// Of which used.
    pub arena_used: usize,
}

/// The runs of the file's `runs` array; an error naming what is missing or malformed.
pub fn runs(text: &str) -> Result<Vec<HostRun>, String> {
    if !text.contains("\"schema\": \"bino-host-frame/1\"") {
        return Err("not a bino-host-frame/1 file".into());
    }
    let at = text.find("\"runs\"").ok_or("no \"runs\"")?;
    let list = &text[at..];
    let end = list.find(']').ok_or("\"runs\" is not closed")?;
    let mut out = Vec::new();
    // Each run is a flat object: no braces inside.
    for object in list[..end].split('{').skip(1) {
        let object = object.split('}').next().unwrap_or_default();
        let field = |key: &str| -> Result<&str, String> {
            let needle = format!("\"{key}\":");
            let start = object.find(&needle).ok_or(format!("a run without \"{key}\""))? + needle.len();
            let value = object[start..].split([',', '\n']).next().unwrap_or_default().trim();
            Ok(value.trim_matches('"'))
        };
        let number = |key: &str| -> Result<usize, String> {
            field(key)?.parse().map_err(|_| format!("\"{key}\" is not a number"))
        };
        let refined = field("refined")?;
        out.push(HostRun {
            preset: field("preset")?.to_string(),
            refined: u32::from_str_radix(refined, 16).map_err(|_| format!("\"refined\" {refined:?} is not hex"))?,
            arena_bytes: number("arena_bytes")?,
            arena_used: number("arena_used")?,
        });
    }
    if out.is_empty() {
        return Err("no runs".into());
    }
    Ok(out)
}
