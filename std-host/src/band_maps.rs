//! Maps as the bands compute them: each band's own token rows, its overlaps included, so a
//! readout can read every band on its own as the core's pathways do (either head reads the
//! rows within [`ROW_REACH`] of those a band keeps, [`Band::around_kept`]), and the kept rows
//! assembled into one map as the band plan assigns them.

use std::ops::Range;

use anyhow::{ensure, Result};
use bino_core::band::Band;
pub use bino_core::model::head::ROW_REACH;

/// Every band's rows of one map: `row_len` values per token row.
#[derive(Debug, Clone, PartialEq)]
pub struct BandedRows<T> {
    /// Token rows of the whole map.
    pub rows: usize,
    /// Values per token row.
    pub row_len: usize,
    /// Each band, top to bottom, with its `band.rows x row_len` values.
    pub bands: Vec<(Band, Vec<T>)>,
}

impl<T: Copy + Default> BandedRows<T> {
    /// The whole map, each row from the band that keeps it.
    pub fn assemble(&self) -> Vec<T> {
        let mut out = vec![T::default(); self.rows * self.row_len];
        for (band, values) in &self.bands {
            let own = self.rows_of(band, band.keep_from..band.keep_to, values);
            out[band.keep_from * self.row_len..band.keep_to * self.row_len].copy_from_slice(own);
        }
        out
    }

    /// Each band with the map rows within `reach` of those it keeps and their values.
    pub fn around_kept(&self, reach: usize) -> impl Iterator<Item = (Band, Range<usize>, &[T])> + '_ {
        self.bands.iter().map(move |(band, values)| {
            let rows = band.around_kept(reach);
            (*band, rows.clone(), self.rows_of(band, rows, values))
        })
    }

    /// Each row of this map followed by the same row of `other`, a map cut into the same bands:
    /// one map for a readout that reads both per band (the export head's two descriptor maps).
    pub fn beside(&self, other: &Self) -> Result<Self> {
        ensure!(
            self.rows == other.rows && self.bands.len() == other.bands.len(),
            "the maps are cut into different bands"
        );
        let bands = (self.bands.iter().zip(&other.bands))
            .map(|((band, a), (other_band, b))| {
                ensure!(band == other_band, "the maps are cut into different bands");
                Ok((
                    *band,
                    (a.chunks_exact(self.row_len).zip(b.chunks_exact(other.row_len)))
                        .flat_map(|(a, b)| a.iter().chain(b).copied())
                        .collect(),
                ))
            })
            .collect::<Result<_>>()?;
        Ok(Self {
            rows: self.rows,
            row_len: self.row_len + other.row_len,
            bands,
        })
    }

    /// The map of the horizontally mirrored view: each row's cells (`cell` values each) in
    /// reverse order, in every band.
    pub fn mirrored(&self, cell: usize) -> Self {
        let bands = (self.bands.iter())
            .map(|(band, values)| {
                let mirrored = (values.chunks_exact(self.row_len))
                    .flat_map(|row| row.chunks_exact(cell).rev().flatten().copied())
                    .collect();
                (*band, mirrored)
            })
            .collect();
        Self { bands, ..self.clone() }
    }

    /// Map rows `rows` (inside `band`) of the band's values.
    fn rows_of<'v>(&self, band: &Band, rows: Range<usize>, values: &'v [T]) -> &'v [T] {
        let from = (rows.start - band.start) * self.row_len;
        &values[from..from + rows.len() * self.row_len]
    }
}

/// Runs a readout on each band's rows around its kept ones ([`BandedRows::around_kept`] by
/// `reach`) and stitches the kept rows of each output into one map.
///
/// `readout(values, rows)` answers, for a map of `rows` token rows, one plane per output
/// (disparity, logits, ...), each `rows x len` values for that plane's row length `len`
/// (the planes in the order and row lengths of `row_lens`).
pub fn per_band<T, U, F>(map: &BandedRows<T>, reach: usize, row_lens: &[usize], mut readout: F) -> Result<Vec<Vec<U>>>
where
    T: Copy + Default,
    U: Copy + Default,
    F: FnMut(&[T], usize) -> Result<Vec<Vec<U>>>,
{
    let mut out: Vec<Vec<U>> = row_lens.iter().map(|&len| vec![U::default(); map.rows * len]).collect();
    for (band, rows, values) in map.around_kept(reach) {
        let planes = readout(values, rows.len())?;
        ensure!(
            planes.len() == row_lens.len(),
            "a band's readout gave {} planes",
            planes.len()
        );
        for ((plane, whole), &len) in planes.iter().zip(&mut out).zip(row_lens) {
            ensure!(
                plane.len() == rows.len() * len,
                "a band's readout plane holds {} values, expected {} rows x {len}",
                plane.len(),
                rows.len()
            );
            let from = (band.keep_from - rows.start) * len;
            let kept = (band.keep_to - band.keep_from) * len;
            whole[band.keep_from * len..band.keep_to * len].copy_from_slice(&plane[from..from + kept]);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use bino_core::band::BandPlan;

    /// A map whose every value names its band and map row: `band * 1000 + row`.
    fn labelled(rows: usize, row_len: usize) -> BandedRows<u32> {
        let bands = BandPlan::new(rows)
            .unwrap()
            .iter()
            .enumerate()
            .map(|(i, band)| {
                let values = (band.start..band.start + band.rows)
                    .flat_map(|row| std::iter::repeat_n(i as u32 * 1000 + row as u32, row_len))
                    .collect();
                (band, values)
            })
            .collect();
        BandedRows { rows, row_len, bands }
    }

    #[test]
    fn the_assembled_map_takes_each_row_from_the_band_that_keeps_it() {
        let map = labelled(30, 3);
        let whole = map.assemble();
        for (i, (band, _)) in map.bands.iter().enumerate() {
            for row in band.keep_from..band.keep_to {
                assert_eq!(whole[row * 3..row * 3 + 3], [i as u32 * 1000 + row as u32; 3]);
            }
        }
    }

    #[test]
    fn each_band_reads_its_own_rows_and_only_its_kept_rows_come_back() {
        let map = labelled(30, 2);
        let mut seen = Vec::new();
        let out = per_band(&map, ROW_REACH, &[1, 2], |values, rows| {
            // Every row comes from one band, and the rows reach around the kept ones.
            let first = values[0];
            seen.push((first / 1000, first % 1000, rows));
            let rows_of = |len: usize| values.chunks_exact(2).flat_map(|r| vec![r[0]; len]).collect();
            Ok(vec![rows_of(1), rows_of(2)])
        })
        .unwrap();
        // 30 rows: bands at 0, 6, 12, 18 keeping 0..9, 9..15, 15..21, 21..30.
        assert_eq!(seen, [(0, 0, 12), (1, 6, 12), (2, 12, 12), (3, 18, 12)]);
        assert_eq!(out[0], map.assemble().chunks_exact(2).map(|r| r[0]).collect::<Vec<_>>());
        assert_eq!(out[1], map.assemble());
        // Two maps side by side, band by band; mirrored, each row's cells reversed.
        let both = map.beside(&labelled(30, 1)).unwrap();
        assert_eq!(both.row_len, 3);
        assert_eq!(&both.bands[1].1[..3], &[1006, 1006, 1006]);
        assert!(map.beside(&labelled(36, 1)).is_err());
        let cells = BandedRows {
            rows: 1,
            row_len: 6,
            bands: vec![(map.bands[0].0, vec![1, 2, 3, 4, 5, 6])],
        };
        assert_eq!(cells.mirrored(2).bands[0].1, [5, 6, 3, 4, 1, 2]);
        assert_eq!(cells.mirrored(2).mirrored(2), cells);
        // A plane of the wrong length is an error, not a shifted map.
        assert!(per_band(&map, 0, &[1], |_, rows| Ok(vec![vec![0u32; rows + 1]])).is_err());
    }
}
