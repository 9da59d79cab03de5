//! The readouts, each defined once for every command (`bino run`, `eval`, `sim`, the firmware
//! through `bino_core::pipeline`): a method's token-grid disparity, optionally with its own
//! left-right check, then bilinear upsampling to pixels (EVAL.md).
//!
//! | readout | token grid |
//! |---|---|
//! | `nolink`, `sgm`, `head` | the method's disparity, every cell |
//! | `nolink+lr`, `sgm+lr`, `head+lr` | the same, cells the method's own left-right check rejects filled from the nearest kept cell to their left (`bino_core::lr::fill_rejected`) |
//!
//! Each method's check compares its left-view disparity with its right-view one: for `nolink`
//! and `sgm` the right view comes from the reindexed cost row (`bino_core::lr`), for `head` from
//! the head on the mirrored pair (`bino_core::model::head::HeadView::Right`).

use std::fmt;
use std::str::FromStr;

use anyhow::{bail, ensure, Context, Result};

use crate::eval::{fill_invalid, upsample_disparity, DisparityMap};

/// How disparity is read from the descriptors.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Method {
    /// Cosine WTA with the parabola step.
    Nolink,
    /// SGM over the cosine costs, then the parabola step.
    Sgm,
    /// The shared head.
    Head,
}

/// A readout: a method, with or without its left-right check and fill.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Readout {
    /// The method.
    pub method: Method,
    /// Fill the cells its left-right check rejects (`+lr`).
    pub lr: bool,
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
    /// Every readout, in the order tables list them.
    pub const ALL: [Readout; 6] = [
        Readout::NOLINK,
        Readout::new(Method::Nolink, true),
        Readout::SGM,
        Readout::new(Method::Sgm, true),
        Readout::HEAD,
        Readout::HEAD_LR,
    ];

    /// `method`, with the left-right fill when `lr`.
    pub const fn new(method: Method, lr: bool) -> Self {
        Self { method, lr }
    }

    /// Its name on the command line and in reports.
    pub fn name(self) -> &'static str {
        match (self.method, self.lr) {
            (Method::Nolink, false) => "nolink",
            (Method::Nolink, true) => "nolink+lr",
            (Method::Sgm, false) => "sgm",
            (Method::Sgm, true) => "sgm+lr",
            (Method::Head, false) => "head",
            (Method::Head, true) => "head+lr",
        }
    }

    /// Whether it needs the shared head.
    pub fn uses_head(self) -> bool {
        self.method == Method::Head
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
            None => bail!("unknown readout {s:?} (expected nolink, sgm or head, each optionally with +lr)"),
        }
    }
}

/// Every method's token-grid disparity (patch columns) of one pair, with its left-right mask.
#[derive(Debug, Clone)]
pub struct MethodMaps {
    /// No-linkage WTA.
    pub nolink: DisparityMap,
    /// SGM.
    pub sgm: DisparityMap,
    /// The shared head, when it ran.
    pub head: Option<DisparityMap>,
    /// Cells whose WTA passes its left-right check.
    pub nolink_consistent: Vec<bool>,
    /// Cells whose SGM passes its left-right check.
    pub sgm_consistent: Vec<bool>,
    /// Cells whose head disparity passes the head's left-right check, when it ran.
    pub head_consistent: Option<Vec<bool>>,
}

impl MethodMaps {
    /// `method`'s disparity and its mask (`None`: the check did not run).
    pub fn method(&self, method: Method) -> Result<(&DisparityMap, Option<&[bool]>)> {
        Ok(match method {
            Method::Nolink => (&self.nolink, Some(&self.nolink_consistent)),
            Method::Sgm => (&self.sgm, Some(&self.sgm_consistent)),
            Method::Head => (
                self.head.as_ref().context("the run had no head")?,
                self.head_consistent.as_deref(),
            ),
        })
    }

    /// The readout's token-grid disparity (see the module table).
    pub fn tokens(&self, readout: Readout) -> Result<DisparityMap> {
        let (map, mask) = self.method(readout.method)?;
        if !readout.lr {
            return Ok(map.clone());
        }
        let mask = mask.with_context(|| format!("{readout}: the left-right check did not run"))?;
        ensure!(
            mask.len() == map.values.len(),
            "{readout}: mask and disparity sizes differ"
        );
        Ok(fill_invalid(map, mask))
    }

    /// The readout's pixel disparity: [`MethodMaps::tokens`] upsampled bilinearly (EVAL.md).
    /// What `bino run` writes and `bino eval` scores.
    pub fn pixels(&self, readout: Readout) -> Result<DisparityMap> {
        Ok(upsample_disparity(&self.tokens(readout)?))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_round_trip_and_unknown_ones_are_errors() {
        for r in Readout::ALL {
            assert_eq!(r.name().parse::<Readout>().unwrap(), r);
        }
        assert_eq!("head+lr".parse::<Readout>().unwrap(), Readout::HEAD_LR);
        let err = format!("{:#}", "head+LR".parse::<Readout>().unwrap_err());
        assert!(err.contains("optionally with +lr"), "{err}");
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
            nolink: map.clone(),
            sgm: map.clone(),
            head: None,
            nolink_consistent: mask.iter().map(|&m| m != 0).collect(),
            sgm_consistent: vec![true; 24],
            head_consistent: None,
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
}
