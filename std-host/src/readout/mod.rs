//! The readouts, each defined once for every command (`bino run`, `eval`, `sim`, the firmware
//! through `bino_core::pipeline`): a method's token-grid disparity, optionally with its own
//! left-right check, then to pixels: bilinear upsampling (EVAL.md), or with `+ref` the integer
//! pixel refinement (`bino_core::refine`, through [`crate::readout::refine`]).
//!
//! | readout | token grid |
//! |---|---|
//! | `nolink`, `sgm`, `head` | the method's disparity, every cell |
//! | `nolink+lr`, `sgm+lr`, `head+lr` | the same, cells the method's own left-right check rejects filled from the nearest kept cell to their left (`bino_core::lr::Fill::FromLeft`); the census's readouts (`census+lr`, `fuse-census+lr`, `fuse-all+lr`, [`census`]) by the lower of the kept cells around each rejected run (`Fill::Background`) |
//! | `fuse` | the weighted mean of `head` and `sgm` in every cell (Q8, `bino_core::lr::fuse_row` with every cell kept; the head's share [`fuse_head_weight`], moved by its confidence) |
//! | `fuse+lr` | `bino_core::lr::fuse_row` of the head and SGM with their own checks: the weighted mean where both pass, the one that passes, else rejected and filled as above |
//!
//! | suffix | pixels |
//! |---|---|
//! | (none) | the token grid upsampled bilinearly (EVAL.md) |
//! | `+ref` (after `+lr` when both: `head+lr+ref`) | the token grid in Q8 ([`crate::readout::refine::tokens_q8`]), refined by `bino_core::refine::sharpness::refine_map_equalised` (sharpness equalisation, then census 5x5, 9x9 box of costs, search +-round(width / 80) px within 2..=8, [`bino_core::refine::RefineParams::for_width`]) on the pair's 8-bit gray views, Q8 px / 256; with `+lr` the pixels of the cells the check rejected keep the bilinear step (`bino_core::refine::keep_rejected_map`) |
//!
//! Every pixel gets a value (the maps are dense); the pixels of rejected cells are known from
//! the method's mask, not from the disparity.
//!
//! Each method's check compares its left-view disparity with its right-view one: for `nolink`
//! and `sgm` the right view comes from the reindexed cost row (`bino_core::lr`), for `head` from
//! the head on the mirrored pair (`bino_core::model::head::HeadView::Right`).

pub mod census;
mod maps;
pub mod pathway;
pub mod refine;

pub use maps::{fuse_grid, MethodMap, MethodMaps, ReadoutGrid};

use std::fmt;
use std::str::FromStr;

use anyhow::{bail, Result};

use crate::eval::DisparityMap;

/// How disparity is read from the descriptors.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Cosine WTA with the parabola step.
    Nolink,
    /// SGM over the cosine costs, then the parabola step.
    Sgm,
    /// The shared head.
    Head,
    /// The head and SGM fused ([`bino_core::lr::fuse_row`]); needs both.
    Fused,
    /// Census matching of the views' pixels with SGM ([`bino_core::census`]); no encoder.
    Census,
    /// The head and the census SGM fused as `Fused` fuses the head and SGM.
    CensusFused,
    /// The head fused with the census SGM, then with the SGM (export pathway).
    FusedAll,
}

/// A readout: a method, with or without its left-right check and fill, upsampled or refined.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Readout {
    /// The method.
    pub method: Method,
    /// Fill the cells its left-right check rejects (`+lr`).
    pub lr: bool,
    /// Pixels by the integer refinement instead of bilinear upsampling (`+ref`).
    pub refine: bool,
}

impl Method {
    /// How its `+lr` readout fills the cells its check rejected: the core's rule
    /// (`bino_core::pipeline::RefineInput::fill`), from the background where the census is in it.
    pub const fn fill(self) -> Fill {
        match self {
            Method::Census | Method::CensusFused | Method::FusedAll => Fill::Background,
            Method::Nolink | Method::Sgm | Method::Head | Method::Fused => Fill::FromLeft,
        }
    }
}

impl Readout {
    /// `nolink`.
    pub const NOLINK: Readout = Readout::new(Method::Nolink, false);
    /// `sgm`.
    pub const SGM: Readout = Readout::new(Method::Sgm, false);
    /// `head`.
    pub const HEAD: Readout = Readout::new(Method::Head, false);
    /// `head+lr`.
    pub const HEAD_LR: Readout = Readout::new(Method::Head, true);
    /// `fuse+lr`.
    pub const FUSED_LR: Readout = Readout::new(Method::Fused, true);
    /// The token-grid readouts (upsampled bilinearly), in the order tables list them.
    pub const UNREFINED: [Readout; 14] = [
        Readout::NOLINK,
        Readout::new(Method::Nolink, true),
        Readout::SGM,
        Readout::new(Method::Sgm, true),
        Readout::HEAD,
        Readout::HEAD_LR,
        Readout::new(Method::Fused, false),
        Readout::FUSED_LR,
        Readout::new(Method::Census, false),
        Readout::new(Method::Census, true),
        Readout::new(Method::CensusFused, false),
        Readout::new(Method::CensusFused, true),
        Readout::new(Method::FusedAll, false),
        Readout::new(Method::FusedAll, true),
    ];
    /// Every readout, in the order tables list them: each unrefined one, then its `+ref`.
    pub const ALL: [Readout; 28] = {
        let mut all = [Readout::NOLINK; 28];
        let mut i = 0;
        while i < 14 {
            all[2 * i] = Readout::UNREFINED[i];
            all[2 * i + 1] = Readout::UNREFINED[i].refined(true);
            i += 1;
        }
        all
    };

    /// `method`, with the left-right fill when `lr`, upsampled bilinearly.
    pub const fn new(method: Method, lr: bool) -> Self {
        Self {
            method,
            lr,
            refine: false,
        }
    }

    /// The same readout, its pixels refined (`+ref`) or not.
    pub const fn refined(self, refine: bool) -> Self {
        Self { refine, ..self }
    }

    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match (self.method, self.lr, self.refine) {
            (Method::Nolink, false, false) => "nolink",
            (Method::Nolink, false, true) => "nolink+ref",
            (Method::Nolink, true, false) => "nolink+lr",
            (Method::Nolink, true, true) => "nolink+lr+ref",
            (Method::Sgm, false, false) => "sgm",
            (Method::Sgm, false, true) => "sgm+ref",
            (Method::Sgm, true, false) => "sgm+lr",
            (Method::Sgm, true, true) => "sgm+lr+ref",
            (Method::Head, false, false) => "head",
            (Method::Head, false, true) => "head+ref",
            (Method::Head, true, false) => "head+lr",
            (Method::Head, true, true) => "head+lr+ref",
            (Method::Fused, false, false) => "fuse",
            (Method::Fused, false, true) => "fuse+ref",
            (Method::Fused, true, false) => "fuse+lr",
            (Method::Fused, true, true) => "fuse+lr+ref",
            (Method::Census, false, false) => "census",
            (Method::Census, false, true) => "census+ref",
            (Method::Census, true, false) => "census+lr",
            (Method::Census, true, true) => "census+lr+ref",
            (Method::CensusFused, false, false) => "fuse-census",
            (Method::CensusFused, false, true) => "fuse-census+ref",
            (Method::CensusFused, true, false) => "fuse-census+lr",
            (Method::CensusFused, true, true) => "fuse-census+lr+ref",
            (Method::FusedAll, false, false) => "fuse-all",
            (Method::FusedAll, false, true) => "fuse-all+ref",
            (Method::FusedAll, true, false) => "fuse-all+lr",
            (Method::FusedAll, true, true) => "fuse-all+lr+ref",
        }
    }

    /// Whether it needs the shared head.
    pub fn uses_head(self) -> bool {
        matches!(
            self.method,
            Method::Head | Method::Fused | Method::CensusFused | Method::FusedAll
        )
    }

    /// Whether it fuses the head with a second opinion (`fuse`, `fuse-census`).
    pub fn fuses(self) -> bool {
        matches!(self.method, Method::Fused | Method::CensusFused | Method::FusedAll)
    }
}

impl fmt::Display for Readout {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Readout {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> Result<Self> {
        match Readout::ALL.iter().find(|r| r.name() == s) {
            Some(&r) => Ok(r),
            None => bail!(
                "unknown readout {s:?} (expected nolink, sgm, head, fuse, census, fuse-census or fuse-all, each optionally with +lr, then optionally +ref)"
            ),
        }
    }
}

/// `map` with the cells `kept` rejects filled by the core's `+lr` fill `fill`
/// ([`bino_core::lr::Fill`]), row by row: the one definition the firmware runs.
pub fn fill_rejected(map: &DisparityMap, kept: &[bool], fill: Fill) -> DisparityMap {
    let mut values = map.values.clone();
    let mask: Vec<u8> = kept.iter().map(|&k| u8::from(k)).collect();
    if map.width > 0 {
        for (row, m) in values.chunks_exact_mut(map.width).zip(mask.chunks_exact(map.width)) {
            // Both slices are one row of `map.width` cells, the only error the fill reports.
            let _ = fill.apply(row, m);
        }
    }
    DisparityMap { values, ..*map }
}

/// The share of `fuse-all`'s first fusion in its second: the core's, which the pipeline uses too.
pub use bino_core::census::FUSE_ALL_FIRST_WEIGHT;

/// The head's share, in 256ths, of a `fuse` cell where both checks pass: the core's rule,
/// which the board's pipeline follows too.
pub use bino_core::lr::{fuse_head_weight, Fill, FUSE_HEAD_HEAVY_MAX_WIDTH};

/// A left-right tolerance in patch columns as the core's Q8.
pub fn lr_tolerance_q8(columns: f32) -> u16 {
    (columns.max(0.0) * 256.0).round().min(u16::MAX as f32) as u16
}

/// Disparity candidates of the heads for views `width` px wide, in patch columns: the core's
/// rule (the StereoSGBM reference's search range at that width, never fewer than the
/// [`HEAD_MAX_DISP`](bino_core::config::HEAD_MAX_DISP) = 12 they were trained with: a w160
/// view's disparities stay below 28 px on the eval split, while 8 % of the w320 ground truth
/// lies above 40 px), which the board presets follow at their width too. Every command and
/// precision uses it, so a readout has one definition per width.
pub use bino_core::config::head_candidates;

#[cfg(test)]
mod tests;
