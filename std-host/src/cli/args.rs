//! Argument groups several verbs share, flattened into each (`#[command(flatten)]`), so a flag
//! is declared, documented and defaulted once. Each group turns into the library's own type.

use bino_core::sgm::Penalties;
use bino_host::data::profile::Profile;
use bino_host::eval::DEFAULT_MAX_COLS;
use clap::Args;

/// `--profile` of the verbs that measure (`bino eval`, `compare`, `reference`): w160 by default,
/// the width of the board's 48x160 band, at which the firmware's results are measured too.
#[derive(Args, Debug, Clone, Copy)]
pub struct MeasureProfile {
    /// Resolution profile: w160, w320 or native; the default is the board's band width.
    #[arg(long, default_value = "w160")]
    pub profile: Profile,
}

/// `--profile` of the verbs that make one pair's output (`bino run`, `bino sim`): w320 by
/// default, the output size the product writes (their default readout is chosen per width).
#[derive(Args, Debug, Clone, Copy)]
pub struct PairProfile {
    /// Resolution profile: w320, w160 or native; the default is the product's output size.
    ///
    /// w320 and w160 resize the views to that width; native keeps their size, whose sides must
    /// then be multiples of 4.
    #[arg(long, default_value = "w320")]
    pub profile: Profile,
}

/// `--max-cols`: how many disparities the cost-volume readouts (nolink, sgm) try, by default
/// [`DEFAULT_MAX_COLS`] (the probe's, for the w160 and w320 profiles; `bino eval`, `compare`,
/// `demo`).
#[derive(Args, Debug, Clone, Copy)]
pub struct Candidates {
    /// Disparity candidates of nolink and sgm, in patch columns.
    #[arg(long, default_value_t = DEFAULT_MAX_COLS)]
    pub max_cols: usize,
}

/// `--max-cols` for the verbs that run one pair at w320 by default (`bino run`, `bino sim`):
/// the same flag, 16 candidates by default.
// Not a const generic of `Candidates`: clap keeps a `default_value_t` string in a static, which
// every instantiation would share.
#[derive(Args, Debug, Clone, Copy)]
pub struct PairCandidates {
    /// Disparity candidates of nolink and sgm, in patch columns.
    #[arg(long, default_value_t = 16)]
    pub max_cols: usize,
}

/// The help text of `--max-cols` for the verbs that describe it by the no-linkage readout
/// (`bino demo`, `bino compare`), set with `#[command(mut_arg("max_cols", ...))]`. No final
/// full stop: clap drops it from a one-line doc comment, and the help must read as before.
pub const NOLINK_CANDIDATES_HELP: &str = "Disparity candidates of the no-linkage readout, in patch columns";

/// `--sgm-p1`, `--sgm-p2`, `--sgm-edge`: the SGM smoothness penalties.
#[derive(Args, Debug, Clone, Copy)]
pub struct SgmPenalties {
    /// SGM penalty for a one-column change (cost units: 4096 = cosine 1).
    #[arg(long, default_value_t = bino_host::demo::DEFAULT_PENALTIES.p1)]
    pub sgm_p1: u16,
    /// SGM penalty for a larger jump.
    #[arg(long, default_value_t = bino_host::demo::DEFAULT_PENALTIES.p2)]
    pub sgm_p2: u16,
    /// Grey-level edge at which the SGM jump penalty halves (0: the same penalty everywhere).
    ///
    /// The grey-level difference between neighbouring cells from which the penalty for a
    /// larger jump is halved.
    #[arg(long, default_value_t = bino_host::demo::DEFAULT_PENALTIES.edge)]
    pub sgm_edge: u8,
}

impl SgmPenalties {
    /// The penalties as the engine takes them.
    pub fn penalties(&self) -> Penalties {
        Penalties {
            p1: self.sgm_p1,
            p2: self.sgm_p2,
            edge: self.sgm_edge,
        }
    }
}

/// `--lr-max-diff`: the left-right check of the `+lr` readouts (and of the LRkeep figures).
#[derive(Args, Debug, Clone, Copy)]
pub struct LeftRightCheck {
    /// Left-right check tolerance, in patch columns.
    #[arg(long, default_value_t = 1.0)]
    pub lr_max_diff: f32,
}

/// `--pathway` of `run` and `sim`: optional, since their default readout runs no encoder.
#[derive(Args, Debug, Clone, Copy)]
pub struct ReadoutPathway {
    /// Pathway of the learned readouts: export (each view encoded alone) or native (one pass).
    ///
    /// export: each view encoded alone, two encoder passes per band; every readout, default
    /// fuse-all+lr. native: one pass on the pair (L, R); the native head's readouts, default
    /// fuse-census+lr (the board's learned preset). Without --pathway and --readout the readout
    /// is census+lr, which runs no encoder; a --readout without --pathway runs on export.
    #[arg(long, value_enum)]
    pub pathway: Option<bino_host::readout::pathway::Pathway>,
}

/// `--pathway`: how each band reaches the readouts.
#[derive(Args, Debug, Clone, Copy)]
pub struct PathwayChoice {
    /// Pathway: export (each view encoded alone) or native (one encoder pass on the pair).
    ///
    /// export: each view encoded alone, two encoder passes per band; every readout. native:
    /// one pass on the pair (L, R); the native head's readouts, head+lr with its right view
    /// read from the same pass.
    #[arg(long, value_enum, default_value_t = bino_host::readout::pathway::Pathway::Export)]
    pub pathway: bino_host::readout::pathway::Pathway,
}
