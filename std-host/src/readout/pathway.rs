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
        let native = matches!(readout.method, Method::Head | Method::Census | Method::CensusFused);
        if self == Pathway::Native && !native {
            bail!(
                "--readout {readout} needs the export pathway: the native pathway's readouts are its head's, \
                 the census SGM's and their fusion (head, census, fuse-census, each optionally with +lr, then +ref)"
            );
        }
        Ok(())
    }

    /// The pathway's learned readout, what `bino run --pathway P` and `bino sim --pathway P`
    /// use when no readout is given (without `--pathway` they use [`DEFAULT_READOUT`]), the one
    /// the streaming pipeline refines by its rule (`RefineInput::for_options`; the board's learned preset runs the
    /// native one): on the export pathway `fuse-all+lr` (the head fused with the census SGM,
    /// then with the descriptor SGM, by their checks: better than `fuse+lr` on all eight
    /// validation sets, `train/experiments.json`, `census_companion`), on the native pathway
    /// `fuse-census+lr` (the native head and the census SGM fused by their checks, better than
    /// the head alone on every validation set: `census_companion`).
    pub fn default_readout(self) -> Readout {
        match self {
            Pathway::Export => Readout::new(Method::FusedAll, true),
            Pathway::Native => Readout::new(Method::CensusFused, true),
        }
    }
}

/// The readout `bino run` and `bino sim` use when neither `--readout` nor `--pathway` is given:
/// `census+lr` (refined, `census+lr+ref`), the census SGM of the pixels with its own check and
/// no encoder. It is more accurate than every learned readout on the real labeled validation
/// pairs at both widths (`train/experiments.json`, `census_default`) and costs a fraction of
/// their instructions on the board.
pub const DEFAULT_READOUT: Readout = Readout::new(Method::Census, true);

/// The readout of a run: `readout` when given, else the named pathway's learned default
/// ([`Pathway::default_readout`]), else [`DEFAULT_READOUT`]; and the pathway it runs on (the
/// export pathway unless named).
pub fn resolve(readout: Option<Readout>, pathway: Option<Pathway>) -> (Readout, Pathway) {
    let chosen = match (readout, pathway) {
        (Some(readout), _) => readout,
        (None, Some(pathway)) => pathway.default_readout(),
        (None, None) => DEFAULT_READOUT,
    };
    (chosen, pathway.unwrap_or_default())
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
    fn the_native_pathway_has_no_descriptor_readouts() {
        for readout in Readout::ALL {
            assert!(Pathway::Export.check(readout).is_ok(), "{readout}");
            let native = Pathway::Native.check(readout);
            let descriptors = matches!(
                readout.method,
                Method::Nolink | Method::Sgm | Method::Fused | Method::FusedAll
            );
            assert_eq!(native.is_ok(), !descriptors, "{readout}");
            if let Err(e) = native {
                assert!(e.to_string().contains("needs the export pathway"), "{e}");
            }
        }
        assert_eq!(Pathway::Export.readouts(), Readout::ALL);
        let native: Vec<_> = Pathway::Native.readouts().iter().map(|r| r.name()).collect();
        assert_eq!(
            native,
            [
                "head",
                "head+ref",
                "head+lr",
                "head+lr+ref",
                "census",
                "census+ref",
                "census+lr",
                "census+lr+ref",
                "fuse-census",
                "fuse-census+ref",
                "fuse-census+lr",
                "fuse-census+lr+ref"
            ]
        );
        for pathway in [Pathway::Export, Pathway::Native] {
            assert!(pathway.check(pathway.default_readout()).is_ok());
            assert_eq!(pathway.core().pathway(), pathway.to_string());
        }
    }

    #[test]
    fn run_and_the_pipeline_read_out_the_same_fusion_on_each_pathway() {
        assert_eq!(Pathway::Export.default_readout().name(), "fuse-all+lr");
        assert_eq!(Pathway::Native.default_readout().name(), "fuse-census+lr");
        // The pipeline's rule refines the same grids; the board's learned preset is the native pathway's.
        let rule = |opts| bino_core::pipeline::RefineInput::for_options(&opts).name();
        for pathway in [Pathway::Export, Pathway::Native] {
            let opts = bino_core::pipeline::Options {
                pathway: pathway.core(),
                ..bino_core::preset::OPTIONS
            };
            assert_eq!(rule(opts), pathway.default_readout().name(), "{pathway}");
        }
        assert_eq!(bino_core::preset::OPTIONS.pathway, Pathway::Native.core());
        assert_eq!(rule(bino_core::preset::OPTIONS), "fuse-census+lr");
        assert_eq!(rule(bino_core::preset::EXPORT_OPTIONS), "fuse-all+lr");
    }

    #[test]
    fn without_a_pathway_the_default_is_the_census_and_with_one_its_learned_readout() {
        let census = resolve(None, None);
        assert_eq!((census.0.name(), census.1), ("census+lr", Pathway::Export));
        // The census runs no encoder: the core streams it as its own input.
        assert!(!census.0.uses_head() && census.0.method == Method::Census);
        assert_eq!(resolve(None, Some(Pathway::Native)).0.name(), "fuse-census+lr");
        assert_eq!(resolve(None, Some(Pathway::Export)).0.name(), "fuse-all+lr");
        let head = Readout::HEAD_LR;
        assert_eq!(resolve(Some(head), None), (head, Pathway::Export));
        assert_eq!(resolve(Some(head), Some(Pathway::Native)), (head, Pathway::Native));
    }
}
