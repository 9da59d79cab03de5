//! `--pathway`: how a command turns a pair into readouts (`bino_core::pipeline::Pathway`).
//!
//! - `export`: every band encoded twice, on (L, L) and (R, R); the descriptor maps feed every
//!   readout (nolink, sgm and the shared head, each with its own left-right check).
//! - `native`: every band encoded once, on the actual pair (L, R); the native head reads the
//!   fused grid. Its readouts are the head's (`head`, `head+lr`, each optionally `+ref`);
//!   `head+lr` costs a second pass, on the mirrored pair.

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

    /// The readout a command uses when none is given: sgm+lr on the export pathway (the lowest
    /// unrefined eval-split error at w320, README), head+lr on the native one (its only checked
    /// readout).
    pub fn default_readout(self) -> Readout {
        match self {
            Pathway::Export => Readout::new(Method::Sgm, true),
            Pathway::Native => Readout::HEAD_LR,
        }
    }
}

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
            assert_eq!(native.is_ok(), readout.uses_head(), "{readout}");
            if let Err(e) = native {
                assert!(e.to_string().contains("needs the export pathway"), "{e}");
            }
        }
        assert_eq!(Pathway::Export.readouts(), Readout::ALL);
        let native: Vec<_> = Pathway::Native.readouts().iter().map(|r| r.name()).collect();
        assert_eq!(native, ["head", "head+ref", "head+lr", "head+lr+ref"]);
        for pathway in [Pathway::Export, Pathway::Native] {
            assert!(pathway.check(pathway.default_readout()).is_ok());
            assert_eq!(pathway.core().pathway(), pathway.to_string());
        }
    }
}
