//! Unit tests that need an input outside the repository (`../shared/data`, the project's Python
//! environment): they skip with a note where it is missing, but under `CI=true` or
//! `BINO_REQUIRE_DATA=1` (which `scripts/test.sh` sets) they fail instead, so a missing input
//! never passes in CI. The same rule as the integration tests' `common::available`.

/// Whether a missing input must fail the test.
pub fn inputs_required() -> bool {
    let set = |name: &str, values: &[&str]| std::env::var(name).is_ok_and(|v| values.contains(&v.as_str()));
    set("CI", &["true", "1"]) || set("BINO_REQUIRE_DATA", &["1", "true"])
}

/// Notes a skip of a test whose input `what` is missing, or panics where [`inputs_required`].
pub fn skip(what: &str) {
    assert!(
        !inputs_required(),
        "{what} is missing (CI=true or BINO_REQUIRE_DATA=1: not skipped)"
    );
    eprintln!("skipped: {what} is missing (set BINO_REQUIRE_DATA=1 to fail instead)");
}
