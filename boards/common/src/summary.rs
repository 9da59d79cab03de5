//! The board's report of one frame, gathered as the pipeline streams (a
//! [`Sink`]): the refined pixel disparity of the preset's readout (fuse-census+lr, or the fast
//! preset's census+lr) summarised per vertical sector (median and near disparity, and the nearest
//! depth in mm through `bino_core::depth` with the preset's example calibration, what an obstacle
//! check reads), the share of cells the readout's left-right check (the head's, or the census
//! SGM's) confirms per sector, a CRC-32 of the refined rows (to compare with a host run of the
//! same rows), and the cycles each pipeline stage took.

use bino_core::config::CELL_W;
use bino_core::crc32::Crc32;
use bino_core::depth::{DepthModel, DisparityUnit, SectorSummary};
use bino_core::pipeline::{CensusRow, HeadChecked, MatchedRow, Sink, Stage};
use bino_core::preset::CALIBRATION;
use bino_core::Error;

use crate::options::OPTIONS;

/// Vertical sectors the width is split into: the preset's, as the QEMU firmware's.
pub const SECTORS: usize = bino_core::preset::SECTORS;
/// Histogram bins: whole pixels of disparity, 0 to the largest candidate (larger values count
/// in the last bin).
const BINS: usize = OPTIONS.max_cols * CELL_W + 1;

/// A free-running cycle counter (the boards' DWT, extended to 64 bits).
pub trait Clock {
    /// Cycles since some fixed start.
    fn now(&mut self) -> u64;
}

/// A clock that never advances: for host runs, where only the disparity matters.
#[derive(Debug, Clone, Copy, Default)]
pub struct NoClock;

impl Clock for NoClock {
    fn now(&mut self) -> u64 {
        0
    }
}

/// One sector's figures.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Sector {
    /// Median refined disparity, whole pixels (0 for an empty sector).
    pub median_px: u16,
    /// 90th percentile refined disparity, whole pixels: the near side of the sector.
    pub near_px: u16,
    /// Cells of the sector the readout's left-right check confirms (the head's; the census
    /// SGM's on the fast preset), per mille.
    pub consistent_permille: u16,
    /// Nearest depth of the sector's refined pixels, mm (`bino_core::depth` with the preset's
    /// calibration); 0 where no pixel has a depth.
    pub nearest_mm: u32,
}

/// What a run reports; fill it by passing it as the pipeline's sink, then call
/// [`Summary::finish`].
pub struct Summary<C> {
    clock: C,
    width: usize,
    histogram: [[u16; BINS]; SECTORS],
    consistent: [u32; SECTORS],
    cells: [u32; SECTORS],
    refined: Crc32,
    refined_rows: usize,
    depth: SectorSummary<SECTORS>,
    depth_error: Option<Error>,
    stage_cycles: [u64; Stage::ALL.len()],
    current: Option<(usize, u64)>,
}

impl<C: Clock> Summary<C> {
    /// An empty summary for views `width` pixels wide (the profile width the calibration is
    /// scaled to), timed by `clock`; [`Error::OutOfRange`] for a width the depth summary
    /// cannot split into [`SECTORS`].
    pub fn new(width: usize, clock: C) -> Result<Self, Error> {
        let model = DepthModel::new(&CALIBRATION, width, DisparityUnit::Pixels)?;
        Ok(Self {
            clock,
            width,
            histogram: [[0; BINS]; SECTORS],
            consistent: [0; SECTORS],
            cells: [0; SECTORS],
            refined: Crc32::new(),
            refined_rows: 0,
            depth: SectorSummary::new(&model, width)?,
            depth_error: None,
            stage_cycles: [0; Stage::ALL.len()],
            current: None,
        })
    }

    /// The first error the depth summary met (a refined row of another width), if any.
    pub fn depth_error(&self) -> Option<Error> {
        self.depth_error
    }

    /// Closes the last stage's timing (call once the run returns).
    pub fn finish(&mut self) {
        let now = self.clock.now();
        if let Some((i, start)) = self.current.take() {
            self.stage_cycles[i] += now.saturating_sub(start);
        }
    }

    /// Each sector's figures, left to right.
    pub fn sectors(&self) -> [Sector; SECTORS] {
        core::array::from_fn(|s| Sector {
            median_px: percentile(&self.histogram[s], 50),
            near_px: percentile(&self.histogram[s], 90),
            consistent_permille: permille(self.consistent[s], self.cells[s]),
            nearest_mm: self.depth.sectors()[s].nearest_mm.unwrap_or(0),
        })
    }

    /// CRC-32 of every refined row (`width` little-endian `u16`, Q8 px), top to bottom.
    pub fn refined_crc(&self) -> u32 {
        self.refined.finish()
    }

    /// Refined pixel rows received.
    pub fn refined_rows(&self) -> usize {
        self.refined_rows
    }

    /// Cycles spent in each stage, in [`Stage::ALL`] order (zero without a clock).
    pub fn stage_cycles(&self) -> [(Stage, u64); Stage::ALL.len()] {
        core::array::from_fn(|i| (Stage::ALL[i], self.stage_cycles[i]))
    }

    /// Counts a token row's left-right mask into its sectors.
    fn count_checked(&mut self, consistent: &[u8]) {
        let cols = consistent.len();
        for (c, &ok) in consistent.iter().enumerate() {
            let s = self.sector_of(c, cols);
            self.cells[s] += 1;
            self.consistent[s] += u32::from(ok != 0);
        }
    }

    fn sector_of(&self, index: usize, of: usize) -> usize {
        (index * SECTORS / of.max(1)).min(SECTORS - 1)
    }
}

/// The smallest bin at or below which `pct` per cent of the counts lie.
fn percentile(histogram: &[u16], pct: u32) -> u16 {
    let total: u32 = histogram.iter().map(|&c| u32::from(c)).sum();
    let rank = (total * pct).div_ceil(100).max(1);
    let mut seen = 0;
    for (bin, &count) in histogram.iter().enumerate() {
        seen += u32::from(count);
        if seen >= rank {
            return bin as u16;
        }
    }
    0
}

fn permille(part: u32, whole: u32) -> u16 {
    if whole == 0 {
        0
    } else {
        (u64::from(part) * 1000 / u64::from(whole)) as u16
    }
}

impl<C: Clock> Sink for Summary<C> {
    fn stage(&mut self, stage: Stage) {
        let now = self.clock.now();
        if let Some((i, start)) = self.current {
            self.stage_cycles[i] += now.saturating_sub(start);
        }
        let i = Stage::ALL.iter().position(|&s| s == stage).unwrap_or(0);
        self.current = Some((i, now));
    }

    fn matched(&mut self, _row: &MatchedRow<'_>) {}

    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        self.count_checked(row.consistent);
    }

    fn census(&mut self, row: &CensusRow<'_>) {
        self.count_checked(row.consistent);
    }

    fn refined(&mut self, _row: usize, disparity_q8: &[u16]) {
        for (x, &d) in disparity_q8.iter().enumerate() {
            let s = self.sector_of(x, self.width);
            let bin = usize::from(d >> 8).min(BINS - 1);
            let count = &mut self.histogram[s][bin];
            *count = count.saturating_add(1);
            self.refined.update(&d.to_le_bytes());
        }
        if let Err(e) = self.depth.push_row(disparity_q8, None) {
            self.depth_error.get_or_insert(e);
        }
        self.refined_rows += 1;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_of_a_histogram() {
        let mut h = [0u16; BINS];
        h[2] = 5; // five cells at 2 px
        h[10] = 4; // four at 10 px
        h[30] = 1; // one at 30 px
        assert_eq!(percentile(&h, 50), 2);
        assert_eq!(percentile(&h, 90), 10);
        assert_eq!(percentile(&h, 100), 30);
        assert_eq!(percentile(&[0; BINS], 50), 0);
    }

    #[test]
    fn refined_rows_land_in_their_sector() {
        let mut s = Summary::new(16, NoClock).unwrap();
        // Sector k (2 px wide) gets disparity 3k px; the last pixel saturates.
        let row: [u16; 16] = core::array::from_fn(|x| ((x / 2) as u16 * 3) << 8);
        let mut wide = row;
        wide[15] = u16::MAX;
        s.refined(0, &row);
        s.refined(1, &wide);
        let got = s.sectors();
        for (k, sector) in got.iter().enumerate().take(SECTORS - 1) {
            assert_eq!(sector.median_px, 3 * k as u16, "sector {k}");
        }
        assert_eq!(got[SECTORS - 1].median_px, 21);
        assert_eq!(got[SECTORS - 1].near_px, (BINS - 1) as u16);
        assert_eq!(s.refined_rows(), 2);
        // Depth: f 500 px x 60 mm / (disparity x scale 640/16 = 40); sector 0 reads 0 px (no
        // depth), sector 1 3 px: 30000 / 120 = 250 mm; the saturated pixel has none.
        assert_eq!(got[0].nearest_mm, 0);
        assert_eq!(got[1].nearest_mm, 250);
        assert!(s.depth_error().is_none());
    }

    #[test]
    fn consistency_counts_per_sector_and_stage_times_add_up() {
        struct Ticks(u64);
        impl Clock for Ticks {
            fn now(&mut self) -> u64 {
                self.0 += 10;
                self.0
            }
        }
        let mut s = Summary::new(32, Ticks(0)).unwrap();
        s.stage(Stage::Rows);
        s.stage(Stage::EncodeLeft);
        // 8 patch columns: one per sector; the first half confirmed.
        let consistent = [1, 1, 1, 1, 0, 0, 0, 0];
        s.head_checked(&HeadChecked {
            row: 0,
            right_q8: &[0; 8],
            consistent: &consistent,
        });
        s.finish();
        let per = s.sectors();
        assert_eq!(per[0].consistent_permille, 1000);
        assert_eq!(per[7].consistent_permille, 0);
        let cycles = s.stage_cycles();
        assert_eq!(cycles[0], (Stage::Rows, 10));
        assert_eq!(cycles[1], (Stage::EncodeLeft, 10));
        assert_eq!(cycles[2].1, 0);
    }
}
