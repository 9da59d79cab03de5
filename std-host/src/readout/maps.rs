//! One pair's token grids: every method's disparity and left-right mask ([`MethodMaps`]), a
//! readout's grid read from them ([`ReadoutGrid`]) and the fusion of two grids ([`fuse_grid`]).

use std::borrow::Cow;

use anyhow::{ensure, Context, Result};
use bino_core::lr::CheckedRow;
use bino_core::matching::DISPARITY_FRAC_BITS;

use super::refine::{refine_pixels, tokens_q8, GrayViews};
use super::{census, fill_rejected, fuse_head_weight, Method, Readout, FUSE_ALL_FIRST_WEIGHT};
use crate::eval::{upsample_disparity, DisparityMap};

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
            fill_rejected(&map, mask, readout.method.fill())
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
