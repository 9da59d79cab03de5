//! The pairs the commands read: a data folder's `PAIRS.tsv` index ([`pairs`]), views at the
//! EVAL.md resolution profiles ([`profile`]), the built-in procedural scene ([`synthetic`]),
//! and the seeded degradations of the right view ([`nuisance`], [`occlusion`]).

pub mod nuisance;
pub mod occlusion;
pub mod pairs;
pub mod profile;
pub(crate) mod rng;
pub mod synthetic;
