//! The readouts, each defined once for every command (`bino run`, `eval`, `sim`, the firmware
//! through `bino_core::pipeline`): a method's token-grid disparity, optionally with its own
//! left-right check, then to pixels: bilinear upsampling (EVAL.md), or with `+ref` the integer
//! pixel refinement (`bino_core::refine`, through [`crate::readout::refine`]).
//!
//! | readout | token grid |
//! |---|---|
//! | `nolink`, `sgm`, `head` | the method's disparity, every cell |
//! | `nolink+lr`, `sgm+lr`, `head+lr` | the same, cells the method's own left-right check rejects filled from the nearest kept cell to their left (`bino_core::lr::fill_rejected`) |
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
pub mod pathway;
pub mod refine;

use std::borrow::Cow;
use std::fmt;
use std::str::FromStr;

use anyhow::{bail, ensure, Context, Result};
use bino_core::config::{CELL_W, HEAD_CANDIDATES_LIMIT, HEAD_MAX_DISP};
use bino_core::lr::CheckedRow;
use bino_core::matching::DISPARITY_FRAC_BITS;

use crate::eval::{upsample_disparity, DisparityMap};
use crate::readout::refine::{refine_pixels, tokens_q8, GrayViews};

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

/// `map` with the cells `kept` rejects filled by the core's `+lr` fill
/// ([`bino_core::lr::fill_rejected`]), row by row: the one definition the firmware runs.
pub fn fill_rejected(map: &DisparityMap, kept: &[bool]) -> DisparityMap {
    let mut values = map.values.clone();
    let mask: Vec<u8> = kept.iter().map(|&k| u8::from(k)).collect();
    if map.width > 0 {
        for (row, m) in values.chunks_exact_mut(map.width).zip(mask.chunks_exact(map.width)) {
            // Both slices are one row of `map.width` cells, the only error the fill reports.
            let _ = bino_core::lr::fill_rejected(row, m);
        }
    }
    DisparityMap { values, ..*map }
}

/// Every method's token-grid disparity (patch columns) of one pair, with its left-right mask.
#[derive(Debug, Clone)]
pub struct MethodMaps {
    /// No-linkage WTA (export pathway).
    pub nolink: Option<DisparityMap>,
    /// SGM (export pathway).
    pub sgm: Option<DisparityMap>,
    /// The pathway's head (the shared head, or the native pathway's), when it ran.
    pub head: Option<DisparityMap>,
    /// Cells whose WTA passes its left-right check (with `nolink`).
    pub nolink_consistent: Vec<bool>,
    /// Cells whose SGM passes its left-right check (with `sgm`).
    pub sgm_consistent: Vec<bool>,
    /// Cells whose head disparity passes the head's left-right check, when it ran.
    pub head_consistent: Option<Vec<bool>>,
    /// The head's largest candidate probability per cell, Q8 (`confidence_q8`), with `head`:
    /// what `fuse` weighs the head by.
    pub head_confidence: Option<Vec<u16>>,
    /// The pair's views as the pipeline reads them (what `+ref` refines on).
    pub views: GrayViews,
    /// The census SGM's grid and mask, computed from `views` when first asked for.
    pub census: std::cell::OnceCell<(DisparityMap, Vec<bool>)>,
}

/// One method's token-grid disparity and its left-right mask (`None`: the check did not run),
/// borrowed from [`MethodMaps`] or, for `fuse`, computed from it.
pub type MethodMap<'m> = (Cow<'m, DisparityMap>, Option<Cow<'m, [bool]>>);

impl MethodMaps {
    /// `method`'s disparity and its mask (`None`: the check did not run). For `fuse` the
    /// checked fusion ([`bino_core::lr::fuse_row`]) and its mask (cells either method keeps).
    pub fn method(&self, method: Method) -> Result<MethodMap<'_>> {
        fn export<'m>(map: &'m Option<DisparityMap>, name: &str) -> Result<&'m DisparityMap> {
            map.as_ref()
                .with_context(|| format!("the run had no {name} readout (the native pathway has only its head)"))
        }
        Ok(match method {
            Method::Nolink => (
                Cow::Borrowed(export(&self.nolink, "nolink")?),
                Some(Cow::Borrowed(&self.nolink_consistent[..])),
            ),
            Method::Sgm => (
                Cow::Borrowed(export(&self.sgm, "sgm")?),
                Some(Cow::Borrowed(&self.sgm_consistent[..])),
            ),
            Method::Head => (
                Cow::Borrowed(self.head.as_ref().context("the run had no head")?),
                self.head_consistent.as_deref().map(Cow::Borrowed),
            ),
            Method::Census => {
                let (map, kept) = self.census_maps()?;
                (Cow::Borrowed(map), Some(Cow::Borrowed(&kept[..])))
            }
            Method::Fused | Method::CensusFused | Method::FusedAll => {
                let (map, kept) = self.fused(method, true)?;
                (Cow::Owned(map), Some(Cow::Owned(kept)))
            }
        })
    }

    /// The census SGM's grid and mask ([`census::census_grid`]), computed once.
    fn census_maps(&self) -> Result<&(DisparityMap, Vec<bool>)> {
        if self.census.get().is_none() {
            let maps = census::census_grid(&self.views)?;
            let _ = self.census.set(maps);
        }
        self.census.get().context("census: the grid was not kept")
    }

    /// The head and its second opinion (`sgm` for `fuse`, `census` for `fuse-census`; for
    /// `fuse-all` the head fused with the census first, then with `sgm`) fused row by row by
    /// [`bino_core::lr::fuse_row`] on the core's Q8 grid, with their own checks (`checked`) or
    /// with every cell kept (the unchecked readout).
    fn fused(&self, method: Method, checked: bool) -> Result<(DisparityMap, Vec<bool>)> {
        let head = self.head.as_ref().context("the run had no head: fuse needs it")?;
        let every = vec![true; head.values.len()];
        let kept = |mask: &'_ [bool]| -> Vec<bool> {
            if checked {
                mask.to_vec()
            } else {
                every.clone()
            }
        };
        let sgm = || -> Result<(&DisparityMap, Vec<bool>)> {
            let sgm = self
                .sgm
                .as_ref()
                .with_context(|| format!("the run had no sgm readout: {method:?} needs the export pathway"))?;
            Ok((sgm, kept(&self.sgm_consistent)))
        };
        let head_kept = if checked {
            self.head_consistent
                .clone()
                .context("fuse+lr: the head's check did not run")?
        } else {
            every.clone()
        };
        match method {
            Method::CensusFused => {
                let (census, census_kept) = self.census_maps()?;
                let second = (census, kept(census_kept));
                self.fuse_pair((head, head_kept), second, census::FUSE_HEAD_WEIGHT)
            }
            Method::FusedAll => {
                let (first, first_kept) = self.fused(Method::CensusFused, checked)?;
                self.fuse_pair((&first, first_kept), sgm()?, FUSE_ALL_FIRST_WEIGHT)
            }
            _ => self.fuse_pair((head, head_kept), sgm()?, fuse_head_weight(self.views.width)),
        }
    }

    /// `head` and `second` (each a grid and its mask) fused by [`fuse_grid`] with the head's
    /// confidence, the head's share `weight`.
    fn fuse_pair(
        &self,
        (head, head_kept): (&DisparityMap, Vec<bool>),
        (second, second_kept): (&DisparityMap, Vec<bool>),
        weight: u8,
    ) -> Result<(DisparityMap, Vec<bool>)> {
        ensure!(
            (head.width, head.height) == (second.width, second.height),
            "the head and SGM grids differ in size"
        );
        let cells = head.values.len();
        ensure!(
            head_kept.len() == cells && second_kept.len() == cells,
            "fuse: mask and disparity sizes differ"
        );
        let bytes = |m: &[bool]| m.iter().map(|&k| u8::from(k)).collect::<Vec<u8>>();
        let (head_q8, second_q8) = (tokens_q8(head), tokens_q8(second));
        let confidence = self
            .head_confidence
            .as_deref()
            .context("fuse: the head's confidence was not kept")?;
        ensure!(confidence.len() == cells, "fuse: confidence and disparity sizes differ");
        let (head_kept, second_kept) = (bytes(&head_kept), bytes(&second_kept));
        let (out, kept) = fuse_grid(
            (&head_q8, &head_kept),
            confidence,
            (&second_q8, &second_kept),
            head.width,
            weight,
        )?;
        let unit = (1u32 << DISPARITY_FRAC_BITS) as f32;
        let map = DisparityMap {
            values: out.iter().map(|&d| d as f32 / unit).collect(),
            ..*head
        };
        Ok((map, kept.iter().map(|&k| k != 0).collect()))
    }

    /// The readout's token grid (filled by the check for `+lr`) and its method's left-right
    /// mask, computed once (a fused readout fuses once).
    pub fn grid(&self, readout: Readout) -> Result<ReadoutGrid<'_>> {
        let (map, mask) = if readout.fuses() && !readout.lr {
            // The unchecked fusion; the mask is the checked one's, when the head's check ran.
            let mask = match self.head_consistent {
                Some(_) => self.method(readout.method)?.1,
                None => None,
            };
            (Cow::Owned(self.fused(readout.method, false)?.0), mask)
        } else {
            self.method(readout.method)?
        };
        let tokens = if readout.lr {
            let mask = mask
                .as_deref()
                .with_context(|| format!("{readout}: the left-right check did not run"))?;
            ensure!(
                mask.len() == map.values.len(),
                "{readout}: mask and disparity sizes differ"
            );
            fill_rejected(&map, mask)
        } else {
            map.into_owned()
        };
        Ok(ReadoutGrid { tokens, mask })
    }

    /// The readout's token-grid disparity (see the module table).
    pub fn tokens(&self, readout: Readout) -> Result<DisparityMap> {
        Ok(self.grid(readout)?.tokens)
    }

    /// The readout's pixel disparity: [`MethodMaps::tokens`] upsampled bilinearly (EVAL.md),
    /// or refined on [`MethodMaps::views`] for `+ref` ([`crate::readout::refine::refine_pixels`]).
    /// What `bino run` writes and `bino eval` scores.
    pub fn pixels(&self, readout: Readout) -> Result<DisparityMap> {
        self.grid_pixels(&self.grid(readout)?, readout)
    }

    /// [`MethodMaps::pixels`] of a grid already read out ([`MethodMaps::grid`]).
    pub fn grid_pixels(&self, grid: &ReadoutGrid<'_>, readout: Readout) -> Result<DisparityMap> {
        if readout.refine {
            // `grid` checked that a `+lr` readout has its mask.
            let kept = if readout.lr { grid.mask.as_deref() } else { None };
            refine_pixels(&grid.tokens, &self.views, kept).with_context(|| format!("{readout}: refinement"))
        } else {
            Ok(upsample_disparity(&grid.tokens))
        }
    }
}

/// A readout's token grid and its method's left-right mask ([`MethodMaps::grid`]).
pub struct ReadoutGrid<'m> {
    /// Token-grid disparity, filled by the check for a `+lr` readout.
    pub tokens: DisparityMap,
    /// The method's left-right mask on the token grid (`None`: the check did not run).
    pub mask: Option<Cow<'m, [bool]>>,
}

/// The fused grid of whole token maps (`cols` cells a row, Q8, masks 1 = kept): each row by
/// [`bino_core::lr::fuse_row`] from the head's `(disparities, mask)`, its confidence and SGM's
/// `(disparities, mask)`, the head's share `weight`. Returns the fused disparities and mask.
pub fn fuse_grid(
    head: (&[u16], &[u8]),
    head_confidence: &[u16],
    sgm: (&[u16], &[u8]),
    cols: usize,
    weight: u8,
) -> Result<(Vec<u16>, Vec<u8>)> {
    let cells = head.0.len();
    ensure!(
        cols > 0 && cells.is_multiple_of(cols),
        "fuse: {cells} cells are not rows of {cols}"
    );
    ensure!(
        [head.1.len(), head_confidence.len(), sgm.0.len(), sgm.1.len()]
            .iter()
            .all(|&n| n == cells),
        "fuse: the head's and SGM's grids, masks and confidence differ in size"
    );
    let (mut out, mut kept) = (vec![0u16; cells], vec![0u8; cells]);
    fn row<'m>((d, k): (&'m [u16], &'m [u8]), at: std::ops::Range<usize>) -> CheckedRow<'m> {
        CheckedRow {
            disparity_q8: &d[at.clone()],
            kept: &k[at],
        }
    }
    let rows = out.chunks_exact_mut(cols).zip(kept.chunks_exact_mut(cols)).enumerate();
    for (r, (o, ok)) in rows {
        let at = r * cols..(r + 1) * cols;
        let (h, s) = (row(head, at.clone()), row(sgm, at.clone()));
        bino_core::lr::fuse_row(h, &head_confidence[at], s, weight, o, ok).map_err(anyhow::Error::msg)?;
    }
    Ok((out, kept))
}

/// The share of `fuse-all`'s first fusion in its second: the core's, which the pipeline uses too.
pub use bino_core::census::FUSE_ALL_FIRST_WEIGHT;

/// The head's share, in 256ths, of a `fuse` cell where both checks pass: the core's rule,
/// which the board's pipeline follows too.
pub use bino_core::lr::{fuse_head_weight, FUSE_HEAD_HEAVY_MAX_WIDTH};

/// A left-right tolerance in patch columns as the core's Q8.
pub fn lr_tolerance_q8(columns: f32) -> u16 {
    (columns.max(0.0) * 256.0).round().min(u16::MAX as f32) as u16
}

/// Disparity candidates of the heads for views `width` px wide, in patch columns: the
/// StereoSGBM reference's search range at that width (EVAL.md: `numDisparities` 32 px per
/// 160 px of width, 64 px = 16 columns at w320), never fewer than the
/// [`HEAD_MAX_DISP`] = 12 they were trained with (44 px: a w160 view's disparities stay below
/// 28 px on the eval split, while 8 % of the w320 ground truth lies above 40 px). Every command
/// and precision uses it, so a readout has one definition per width.
pub fn head_candidates(width: usize) -> usize {
    let sgbm_px = 16 * (2 * width).div_ceil(160);
    (sgbm_px / CELL_W).clamp(HEAD_MAX_DISP, HEAD_CANDIDATES_LIMIT)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_grid_fusion_is_fuse_row_per_row_and_checks_its_sizes() {
        let (head, sgm) = ([256u16, 512, 768, 1024], [512u16, 512, 256, 0]);
        let (head_kept, sgm_kept, confidence) = ([1u8, 0, 1, 0], [1u8, 1, 0, 0], [128u16; 4]);
        let (out, kept) = fuse_grid((&head, &head_kept), &confidence, (&sgm, &sgm_kept), 2, 128).unwrap();
        assert_eq!((out, kept), (vec![384, 512, 768, 1024], vec![1, 1, 1, 0]));
        assert!(fuse_grid((&head, &head_kept), &confidence, (&sgm, &sgm_kept), 3, 128).is_err());
        let short = &confidence[..3];
        assert!(fuse_grid((&head, &head_kept), short, (&sgm, &sgm_kept), 2, 128).is_err());
    }

    #[test]
    fn names_round_trip_and_unknown_ones_are_errors() {
        for r in Readout::ALL {
            assert_eq!(r.name().parse::<Readout>().unwrap(), r);
            assert_eq!(r.to_string(), r.name());
        }
        let names: std::collections::BTreeSet<_> = Readout::ALL.iter().map(|r| r.name()).collect();
        assert_eq!(names.len(), 28, "distinct names");
        assert_eq!("head+lr".parse::<Readout>().unwrap(), Readout::HEAD_LR);
        assert_eq!(
            "head+lr+ref".parse::<Readout>().unwrap(),
            Readout::HEAD_LR.refined(true)
        );
        assert_eq!(Readout::ALL[1], Readout::NOLINK.refined(true), "each then its +ref");
        for bad in ["head+LR", "head+ref+lr", "ref", "sgm+ref+ref"] {
            let err = format!("{:#}", bad.parse::<Readout>().unwrap_err());
            assert!(err.contains("optionally with +lr, then optionally +ref"), "{err}");
        }
    }

    fn views(width: usize, height: usize) -> GrayViews {
        let left: Vec<u8> = (0..width * height)
            .map(|i| ((i * 97 + i / width * 31) % 251) as u8)
            .collect();
        let right = (0..width * height)
            .map(|i| left[(i / width) * width + (i % width + 5).min(width - 1)])
            .collect();
        GrayViews {
            width,
            height,
            left,
            right,
        }
    }

    /// The host's fill at the token grid is the core's integer `lr::fill_rejected`, value for
    /// value (a copy of kept values, so exact in any precision).
    #[test]
    fn the_fill_is_the_cores() {
        let q8: Vec<u16> = (0..24).map(|i| (i * 37 % 11) as u16 * 64).collect();
        let mask: Vec<u8> = (0..24).map(|i| u8::from(i % 3 == 1 || i % 7 == 0)).collect();
        let map = DisparityMap {
            width: 8,
            height: 3,
            values: q8.iter().map(|&d| d as f32 / 256.0).collect(),
        };
        let maps = MethodMaps {
            nolink: Some(map.clone()),
            sgm: Some(map.clone()),
            head: None,
            nolink_consistent: mask.iter().map(|&m| m != 0).collect(),
            sgm_consistent: vec![true; 24],
            head_consistent: None,
            head_confidence: None,
            views: views(32, 12),
            census: Default::default(),
        };
        let host = maps.tokens(Readout::new(Method::Nolink, true)).unwrap();
        let mut core = q8.clone();
        for (row, m) in core.chunks_exact_mut(8).zip(mask.chunks_exact(8)) {
            bino_core::lr::fill_rejected(row, m).unwrap();
        }
        let core: Vec<f32> = core.iter().map(|&d| d as f32 / 256.0).collect();
        assert_eq!(host.values, core);
        assert!(maps.tokens(Readout::HEAD).is_err(), "no head in this run");
    }

    /// A `+ref` readout's pixels are the core's whole-map refinement (equalised:
    /// `refine_map_equalised`) of the readout's token grid (after the fill) in Q8 on the views,
    /// with `+lr` the rejected cells' pixels kept at the bilinear step (`keep_rejected_map`),
    /// Q8 px / 256; without `+ref` the bilinear upsampling.
    #[test]
    fn the_refined_pixels_are_the_cores_equalised_whole_map() {
        use bino_core::refine::sharpness::refine_map_equalised;
        use bino_core::refine::{keep_rejected_map, scratch_len, RefineParams};
        let q8: Vec<u16> = (0..24).map(|i| 250 + (i * 37 % 11) as u16 * 9).collect();
        let mask: Vec<bool> = (0..24).map(|i| i % 5 != 2).collect();
        let map = DisparityMap {
            width: 8,
            height: 3,
            values: q8.iter().map(|&d| d as f32 / 256.0).collect(),
        };
        let maps = MethodMaps {
            nolink: Some(map.clone()),
            sgm: Some(map.clone()),
            head: Some(map.clone()),
            nolink_consistent: mask.clone(),
            sgm_consistent: mask.clone(),
            head_consistent: Some(mask.clone()),
            head_confidence: Some((0..24).map(|i| (i * 23 % 256) as u16).collect()),
            views: views(32, 12),
            census: Default::default(),
        };
        let v = &maps.views;
        // The census readouts' grids come from the views, not from `q8` (their own test).
        let from_q8 = Readout::ALL
            .into_iter()
            .filter(|r| !matches!(r.method, Method::Census | Method::CensusFused | Method::FusedAll));
        for readout in from_q8 {
            let pixels = maps.pixels(readout).unwrap();
            assert_eq!((pixels.width, pixels.height), (32, 12), "{readout}");
            let tokens = maps.tokens(readout).unwrap();
            if !readout.refine {
                assert_eq!(pixels, upsample_disparity(&tokens), "{readout}");
                continue;
            }
            let mut grid = q8.clone();
            if readout.lr {
                let m: Vec<u8> = mask.iter().map(|&k| u8::from(k)).collect();
                for (row, m) in grid.chunks_exact_mut(8).zip(m.chunks_exact(8)) {
                    bino_core::lr::fill_rejected(row, m).unwrap();
                }
            }
            let params = RefineParams::for_width(32);
            let mut scratch = vec![0u32; scratch_len(32, &params)];
            let mut out = vec![0u16; 32 * 12];
            refine_map_equalised(&v.left, &v.right, 32, &grid, &params, &mut scratch, &mut out).unwrap();
            if readout.lr {
                let m: Vec<u8> = mask.iter().map(|&k| u8::from(k)).collect();
                keep_rejected_map(32, &grid, &m, &mut out).unwrap();
            }
            let core: Vec<f32> = out.iter().map(|&d| d as f32 / 256.0).collect();
            assert_eq!(pixels.values, core, "{readout}");
        }
        let refined = maps.pixels(Readout::SGM.refined(true)).unwrap();
        assert!(
            refined.values.iter().filter(|&&d| (d - 5.0).abs() < 0.25).count() > 32 * 12 / 2,
            "the refinement finds the views' 5 px shift"
        );
    }

    /// The rule `train/bino_train/head.py::head_candidates` repeats (its test pins the same
    /// values): SGBM's range at the width, never below the trained 12, at most the limit.
    #[test]
    fn head_candidates_follow_the_sgbm_range_of_the_width() {
        let counts: Vec<usize> = [32, 160, 320, 400, 4000].into_iter().map(head_candidates).collect();
        assert_eq!(counts, [12, 12, 16, 20, 64]);
    }
}
