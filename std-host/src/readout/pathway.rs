//! `--pathway`: how a command turns a pair into readouts (`bino_core::pipeline::Pathway`).
//!
//! - `export`: every band encoded twice, on (L, L) and (R, R); the descriptor maps feed every
//!   readout (nolink, sgm and the shared head, each with its own left-right check).
//! - `native`: every band encoded once, on the actual pair (L, R); the native head reads the
//!   fused grid. Its readouts are the head's (`head`, `head+lr`, each optionally `+ref`);
//!   `head+lr` reads the right view from the same pass (the head's logits along their diagonal).

use anyhow::{bail, Result};

use crate::readout::{Method, Readout};

/// The pathway of a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum Pathway {
    /// Two encoder passes per band, descriptors for every readout.
    #[default]
    Export,
    /// One encoder pass per band on (L, R), the native head.
    Native,
}

impl Pathway {
    /// The core pipeline's pathway.
    pub fn core(self) -> bino_core::pipeline::Pathway {
        match self {
            Pathway::Export => bino_core::pipeline::Pathway::Export,
            Pathway::Native => bino_core::pipeline::Pathway::Native,
        }
    }

    /// Its name, as `--pathway` spells it.
    pub fn name(self) -> &'static str {
        self.core().pathway()
    }

    /// An error unless `readout` exists on this pathway (the native one has only its head).
    pub fn check(self, readout: Readout) -> Result<()> {
        if self == Pathway::Native && readout.method != Method::Head {
            bail!(
                "--readout {readout} needs the export pathway: the native pathway's readouts are its head's \
                 (head, head+lr, each optionally +ref)"
            );
        }
        Ok(())
    }

    /// The readout `bino run` uses when none is given: on the export pathway `fuse+lr` (the
    /// head and SGM fused by their checks, better than either on every validation set at 160
    /// and 320 px: `train/experiments.json`, `fused_readout`), on the native pathway `head+lr`
    /// (its only checked readout).
    pub fn default_readout(self) -> Readout {
        match self {
            Pathway::Export => Readout::FUSED_LR,
            Pathway::Native => Readout::HEAD_LR,
        }
    }

    /// The readout the board's streaming pipeline refines ([`bino_core::preset`], what `bino
    /// sim` shows by default), for views `view_width` px wide: on the export pathway head+lr up
    /// to [`HEAD_DEFAULT_MAX_WIDTH`] and sgm+lr above, on the native pathway head+lr. The
    /// pipeline does not stream the fused readout yet.
    pub fn board_readout(self, view_width: usize) -> Readout {
        match self {
            Pathway::Export if view_width > HEAD_DEFAULT_MAX_WIDTH => Readout::new(Method::Sgm, true),
            Pathway::Export | Pathway::Native => Readout::HEAD_LR,
        }
    }
}

/// Widest view (px) whose board readout on the export pathway is head+lr rather than sgm+lr. Chosen off the
/// eval split, on the 22 held-out train pairs against left-right-consistent StereoSGBM
/// (`bino_train.val_folder`, `bino eval --split val`), int8, refined (as `bino run` writes):
/// head+lr+ref against sgm+lr+ref 0.483 / 0.542 px epe at 160 px, 0.522 / 0.506 at 200, 0.611 /
/// 0.587 at 240, 0.718 / 0.591 at 280, 0.842 / 0.661 at 320. The head was trained on 0-44 px
/// disparities, which a wider view exceeds; the boards' 160-px bands refine head+lr too.
pub const HEAD_DEFAULT_MAX_WIDTH: usize = 160;

impl Pathway {
    /// The readouts `bino eval` scores when none are named: every readout of the pathway,
    /// each unrefined then refined.
    pub fn readouts(self) -> Vec<Readout> {
        Readout::ALL.into_iter().filter(|&r| self.check(r).is_ok()).collect()
    }
}

impl std::fmt::Display for Pathway {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_native_pathway_has_only_head_readouts() {
        for readout in Readout::ALL {
            assert!(Pathway::Export.check(readout).is_ok(), "{readout}");
            let native = Pathway::Native.check(readout);
            assert_eq!(native.is_ok(), readout.method == Method::Head, "{readout}");
            if let Err(e) = native {
                assert!(e.to_string().contains("needs the export pathway"), "{e}");
            }
        }
        assert_eq!(Pathway::Export.readouts(), Readout::ALL);
        let native: Vec<_> = Pathway::Native.readouts().iter().map(|r| r.name()).collect();
        assert_eq!(native, ["head", "head+ref", "head+lr", "head+lr+ref"]);
        for pathway in [Pathway::Export, Pathway::Native] {
            assert!(pathway.check(pathway.default_readout()).is_ok());
            for width in [160, 320, 1280] {
                assert!(pathway.check(pathway.board_readout(width)).is_ok());
            }
            assert_eq!(pathway.core().pathway(), pathway.to_string());
        }
    }

    #[test]
    fn run_fuses_and_the_board_readout_follows_the_view_width() {
        assert_eq!(Pathway::Export.default_readout().name(), "fuse+lr");
        assert_eq!(Pathway::Native.default_readout().name(), "head+lr");
        let name = |p: Pathway, w: usize| p.board_readout(w).name();
        assert_eq!(name(Pathway::Export, 160), "head+lr");
        assert_eq!(name(Pathway::Export, 161), "sgm+lr");
        assert_eq!(name(Pathway::Export, 320), "sgm+lr");
        assert_eq!(name(Pathway::Native, 320), "head+lr");
    }
}
