//! Depth in millimetres and an obstacle summary per column sector, from Q8 disparity rows
//! (feature `depth`).
//!
//! The readouts give disparities at the resolution profile's width (`bino run --profile w160`
//! resizes every view to 160 px), in Q8 patch columns (token grids) or Q8 pixels (the refined
//! rows). A stereo board's calibration is in pixels of the full sensor image. [`DepthModel`]
//! bridges the two: with `scale = sensor width / profile width` (4 for a 640-px sensor at w160),
//!
//! ```text
//! disparity_px (sensor) = disparity_q8 / 256 * unit_px * scale
//! depth_mm              = focal_px * baseline_mm / disparity_px
//! ```
//!
//! where `unit_px` is 1 for pixel rows and [`CELL_W`] for patch columns. A zero disparity, a
//! saturated one (`u16::MAX`, see [`crate::refine`]) and a cell the left-right check rejected
//! have no depth ([`None`]), never infinity or a panic.
//!
//! Float use is confined to [`DepthModel::new`] and [`SectorSummary::new`] (done once per
//! calibration; `atan` from `micromath`, so it builds without `std` or an FPU); per cell, the
//! depth is one integer division. The int8 pipeline never sees a float.
//!
//! ```
//! use bino_core::depth::{Calibration, DepthModel, DisparityUnit, SectorSummary};
//! // A 640-px sensor, f = 500 px, 60 mm baseline, read at the w160 profile (scale 4).
//! let cal = Calibration { focal_px: 500.0, principal_x_px: 320.0, baseline_mm: 60.0, sensor_width_px: 640 };
//! let model = DepthModel::new(&cal, 160, DisparityUnit::Pixels)?;
//! // 10 px at w160 = 40 sensor px: 500 * 60 / 40 = 750 mm.
//! assert_eq!(model.depth_mm(10 * 256), Some(750));
//! assert_eq!(model.depth_mm(0), None);
//! let mut sectors = SectorSummary::<4>::new(&model, 160)?;
//! let mut row = [5 * 256u16; 160];
//! row[150] = 20 * 256; // something near, in the right-most sector
//! sectors.push_row(&row, None)?;
//! assert_eq!(sectors.sectors()[3].nearest_mm, Some(375));
//! assert_eq!(sectors.sectors()[0].nearest_mm, Some(1500));
//! assert!(sectors.sectors()[0].bearing_rad < 0.0); // left of the optical axis
//! # Ok::<(), bino_core::Error>(())
//! ```

use crate::config::CELL_W;
use crate::Error;
use micromath::F32;

/// Fractional bits of the Q8 disparities the readouts emit.
const Q8: f32 = 256.0;
/// The largest focal length (px) and baseline (mm) taken: far beyond any stereo board, small
/// enough that the depth numerator stays exact in `u64`.
const MAX_CALIBRATION: f32 = 1.0e6;

/// A rectified stereo camera's calibration, in pixels of the full sensor image.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Calibration {
    /// Focal length, px (1 to 1e6).
    pub focal_px: f32,
    /// Principal point column, px from the left edge (0 to `sensor_width_px`).
    pub principal_x_px: f32,
    /// Distance between the two optical centres, mm (above 0, at most 1e6).
    pub baseline_mm: f32,
    /// Width of the calibrated image, px (positive).
    pub sensor_width_px: u32,
}

/// What one step of a disparity value (256 in Q8) means, at the profile's width.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DisparityUnit {
    /// One pixel (the refined rows, [`crate::refine`]).
    Pixels,
    /// One patch column, [`CELL_W`] pixels (the token-grid readouts: WTA, SGM, head).
    PatchColumns,
}

impl DisparityUnit {
    /// Profile pixels per unit.
    pub const fn pixels(self) -> usize {
        match self {
            DisparityUnit::Pixels => 1,
            DisparityUnit::PatchColumns => CELL_W,
        }
    }
}

/// Turns Q8 disparities of one profile into depths (see the [module docs](self)).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DepthModel {
    calibration: Calibration,
    profile_width_px: usize,
    unit: DisparityUnit,
    /// `focal_px * baseline_mm * 256 / (unit_px * scale)` in Q16 (times 2^16): depth in mm
    /// times the Q8 disparity, with 16 fraction bits so that rounding it moves a depth by at
    /// most 2^-17 mm (an integer numerator moved it by up to 0.5 mm / disparity: the `depth`
    /// fuzz target found 65 mm for 64.497).
    numerator_q16: u64,
}

impl DepthModel {
    /// A model for disparities in `unit` at a profile `profile_width_px` wide, from `calibration`
    /// ([`Error::OutOfRange`] names a calibration value outside its documented range, or a profile
    /// width of zero or wider than the sensor).
    pub fn new(calibration: &Calibration, profile_width_px: usize, unit: DisparityUnit) -> Result<Self, Error> {
        check_range("focal length (px)", calibration.focal_px, 1.0)?;
        check_range("baseline (mm)", calibration.baseline_mm, f32::MIN_POSITIVE)?;
        let sensor = calibration.sensor_width_px as usize;
        let cx = calibration.principal_x_px;
        if !(cx >= 0.0 && cx <= sensor as f32) {
            // NaN fails the comparison too (reported as 0).
            return Err(Error::OutOfRange {
                what: "principal point (px)",
                value: cx as usize,
                min: 0,
                max: sensor,
            });
        }
        if profile_width_px == 0 || profile_width_px > sensor {
            return Err(Error::OutOfRange {
                what: "profile width (px)",
                value: profile_width_px,
                min: 1,
                max: sensor,
            });
        }
        let scale = sensor as f32 / profile_width_px as f32;
        let numerator = calibration.focal_px * calibration.baseline_mm * Q8 / (unit.pixels() as f32 * scale);
        Ok(Self {
            calibration: *calibration,
            profile_width_px,
            unit,
            // At most 1e6 * 1e6 * 256 * 2^16 < 1.7e19 < u64::MAX (2^64 = 1.8e19).
            numerator_q16: (f64::from(numerator) * f64::from(1u32 << NUMERATOR_FRAC_BITS) + 0.5) as u64,
        })
    }

    /// The calibration it was made from.
    pub const fn calibration(&self) -> &Calibration {
        &self.calibration
    }

    /// Sensor pixels per profile pixel (4 for a 640-px sensor at w160).
    pub fn scale(&self) -> f32 {
        self.calibration.sensor_width_px as f32 / self.profile_width_px as f32
    }

    /// The disparity unit.
    pub const fn unit(&self) -> DisparityUnit {
        self.unit
    }

    /// Depth in mm (rounded to the nearest mm) of a Q8 disparity; [`None`] for zero and for the
    /// saturated `u16::MAX`, which mean "no match" rather than "infinitely far". Within 0.5 mm
    /// (the rounding) plus 1e-6 relative (the f32 setup) plus 1e-5 mm (the Q16 numerator) of
    /// the exact `f * b / (disparity * unit * scale)`.
    pub fn depth_mm(&self, disparity_q8: u16) -> Option<u32> {
        if disparity_q8 == 0 || disparity_q8 == u16::MAX {
            return None;
        }
        // One 64-bit division (a library call on Cortex-M, once per refined pixel: far below
        // the refinement's own cost).
        let d = u64::from(disparity_q8) << NUMERATOR_FRAC_BITS;
        let mm = self.numerator_q16.saturating_add(d / 2) / d;
        Some(u32::try_from(mm).unwrap_or(u32::MAX))
    }

    /// Bearing of a profile column position `x_px` (0 = the left edge of the profile image),
    /// radians, positive to the right of the optical axis: `atan((x * scale - cx) / f)`, within
    /// 0.003 rad (0.16 degrees) of the exact value (`micromath`'s `atan`); a non-finite `x_px`
    /// gives 0.
    pub fn bearing_rad(&self, x_px: f32) -> f32 {
        let c = &self.calibration;
        let tan = (x_px * self.scale() - c.principal_x_px) / c.focal_px;
        if tan.is_finite() {
            // Beyond 1e6 the angle is pi/2 to f32 precision; the clamp keeps atan's squares finite.
            F32(tan.clamp(-1.0e6, 1.0e6)).atan().0
        } else {
            0.0
        }
    }
}

/// What a column sector holds: the nearest depth seen in it and where it points.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Sector {
    /// First column of the sector in the disparity rows.
    pub first_col: u16,
    /// One past its last column.
    pub end_col: u16,
    /// Bearing of the sector's centre, radians, positive to the right ([`DepthModel::bearing_rad`]).
    pub bearing_rad: f32,
    /// Nearest depth in the sector, mm; [`None`] while no cell had a depth.
    pub nearest_mm: Option<u32>,
    /// Row index (from 0, in pushed rows) of the nearest depth.
    pub nearest_row: u16,
    /// Cells with a depth.
    pub cells: u32,
}

/// The nearest depth in each of `N` equal column sectors, over the rows pushed so far: the
/// obstacle summary a robot reads off a stereo board.
///
/// Columns `[i * cols / N, (i + 1) * cols / N)` form sector `i`, left to right.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SectorSummary<const N: usize> {
    model: DepthModel,
    cols: usize,
    rows: usize,
    sectors: [Sector; N],
}

impl<const N: usize> SectorSummary<N> {
    /// An empty summary for rows of `cols` disparities spanning the profile's width; `N` must
    /// be 1 to `cols` and `cols` at most `u16::MAX` ([`Error::OutOfRange`]).
    pub fn new(model: &DepthModel, cols: usize) -> Result<Self, Error> {
        if cols == 0 || cols > usize::from(u16::MAX) {
            return Err(out_of_range("disparity row length", cols));
        }
        if N == 0 || N > cols {
            return Err(Error::OutOfRange {
                what: "sectors",
                value: N,
                min: 1,
                max: cols,
            });
        }
        let px_per_col = model.profile_width_px as f32 / cols as f32;
        let sectors = core::array::from_fn(|i| {
            let (first, end) = (i * cols / N, (i + 1) * cols / N);
            Sector {
                first_col: first as u16,
                end_col: end as u16,
                bearing_rad: model.bearing_rad((first + end) as f32 * 0.5 * px_per_col),
                nearest_mm: None,
                nearest_row: 0,
                cells: 0,
            }
        });
        Ok(Self {
            model: *model,
            cols,
            rows: 0,
            sectors,
        })
    }

    /// Adds one disparity row (`cols` Q8 values); with `keep`, only the cells where it is
    /// non-zero (a left-right mask). [`Error::BufferSize`] on a row or mask of another length.
    pub fn push_row(&mut self, disparity_q8: &[u16], keep: Option<&[u8]>) -> Result<(), Error> {
        Error::check_len("sector disparity row", self.cols, disparity_q8.len())?;
        if let Some(k) = keep {
            Error::check_len("sector keep mask", self.cols, k.len())?;
        }
        let row = u16::try_from(self.rows).unwrap_or(u16::MAX);
        for sector in &mut self.sectors {
            let cols = usize::from(sector.first_col)..usize::from(sector.end_col);
            let (Some(row_cols), keep_cols) = (disparity_q8.get(cols.clone()), keep.and_then(|k| k.get(cols))) else {
                continue; // not reached: the sectors tile 0..cols and the lengths were checked
            };
            for (c, &d) in row_cols.iter().enumerate() {
                if keep_cols.is_some_and(|k| k.get(c) == Some(&0)) {
                    continue;
                }
                let Some(mm) = self.model.depth_mm(d) else { continue };
                sector.cells = sector.cells.saturating_add(1);
                if sector.nearest_mm.is_none_or(|n| mm < n) {
                    sector.nearest_mm = Some(mm);
                    sector.nearest_row = row;
                }
            }
        }
        self.rows = self.rows.saturating_add(1);
        Ok(())
    }

    /// The sectors, left to right.
    pub const fn sectors(&self) -> &[Sector; N] {
        &self.sectors
    }

    /// Rows pushed so far.
    pub const fn rows(&self) -> usize {
        self.rows
    }

    /// The nearest sector with a depth: its index and depth in mm.
    pub fn nearest(&self) -> Option<(usize, u32)> {
        self.sectors
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.nearest_mm.map(|mm| (i, mm)))
            .min_by_key(|&(_, mm)| mm)
    }
}

/// `Ok` when `min <= v <= MAX_CALIBRATION`; the error reports `v` truncated (NaN as 0).
/// Fraction bits of [`DepthModel`]'s numerator.
const NUMERATOR_FRAC_BITS: u32 = 16;

fn check_range(what: &'static str, v: f32, min: f32) -> Result<(), Error> {
    if v >= min && v <= MAX_CALIBRATION {
        Ok(())
    } else {
        Err(out_of_range(what, v as usize))
    }
}

fn out_of_range(what: &'static str, value: usize) -> Error {
    Error::OutOfRange {
        what,
        value,
        min: 0,
        max: MAX_CALIBRATION as usize,
    }
}
