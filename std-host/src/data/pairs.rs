//! The `PAIRS.tsv` index of a stereo data folder (see `../shared/data/DATA.md`).
//!
//! Columns are found by name, paths are relative to the index's folder, and every malformed
//! line is reported with its line number.

use std::fmt;
use std::path::{Path, PathBuf};

use anyhow::{bail, ensure, Context, Result};

/// Which use a pair is for.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Split {
    /// Unlabeled pairs that training may use.
    Train,
    /// Labeled pairs for evaluation only: never trained on, not even self-supervised.
    Eval,
    /// Train pairs held out of head training with proxy ground truth (confident StereoSGBM),
    /// written by `python -m bino_train.val_folder`: for choosing settings off the eval split.
    Val,
}

impl fmt::Display for Split {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Split::Train => "train",
            Split::Eval => "eval",
            Split::Val => "val",
        })
    }
}

/// How a ground-truth file stores disparity: the `gt_format` column.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GtFormat {
    /// `pgm_u8`: 8-bit single-channel PGM (Middlebury 2001-2005).
    PgmU8,
    /// `png_u8`: 8-bit single-channel PNG.
    PngU8,
    /// `png_u16`: 16-bit single-channel PNG (KITTI: `gt_scale` 256, `gt_invalid` 0).
    PngU16,
    /// `pfm`: one-channel float32 PFM in pixels (Middlebury 2014, ETH3D: `gt_scale` 1);
    /// non-finite values (`inf`, NaN) mean "no ground truth".
    Pfm,
}

impl GtFormat {
    /// Every format, in the order the error for an unknown one lists them.
    pub const ALL: [GtFormat; 4] = [GtFormat::PgmU8, GtFormat::PngU8, GtFormat::PngU16, GtFormat::Pfm];

    /// The name `PAIRS.tsv` uses.
    pub fn name(self) -> &'static str {
        match self {
            GtFormat::PgmU8 => "pgm_u8",
            GtFormat::PngU8 => "png_u8",
            GtFormat::PngU16 => "png_u16",
            GtFormat::Pfm => "pfm",
        }
    }

    /// The format called `name` in `PAIRS.tsv`.
    pub fn from_name(name: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|f| f.name() == name)
    }

    /// The largest `gt_invalid` the format can store (`None`: it stores floats).
    fn max_invalid(self) -> Option<u16> {
        match self {
            GtFormat::PgmU8 | GtFormat::PngU8 => Some(u8::MAX.into()),
            GtFormat::PngU16 => Some(u16::MAX),
            GtFormat::Pfm => None,
        }
    }
}

impl fmt::Display for GtFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Ground truth of a labeled pair: disparity of the left image = stored value / `scale`, for
/// every format (so a PFM in pixels has `gt_scale` 1, a KITTI PNG 256).
#[derive(Debug, Clone, PartialEq)]
pub struct GroundTruth {
    /// Disparity image file.
    pub path: PathBuf,
    /// How the file stores disparity.
    pub format: GtFormat,
    /// Divisor from stored value to disparity in pixels.
    pub scale: f32,
    /// Stored value that means "no ground truth". Required for the integer formats (within
    /// their range); optional for `pfm`, whose non-finite values always mean it.
    pub invalid: Option<u16>,
}

/// One row of `PAIRS.tsv`, paths resolved against the index's folder.
#[derive(Debug, Clone, PartialEq)]
pub struct PairRecord {
    /// Unique name.
    pub pair_id: String,
    /// Train or eval.
    pub split: Split,
    /// Source dataset name.
    pub dataset: String,
    /// Left image file.
    pub left: PathBuf,
    /// Right image file.
    pub right: PathBuf,
    /// Ground truth, for eval pairs.
    pub gt: Option<GroundTruth>,
    /// Original width in pixels.
    pub width: usize,
    /// Original height in pixels.
    pub height: usize,
}

const COLUMNS: [&str; 11] = [
    "pair_id",
    "split",
    "dataset",
    "left",
    "right",
    "gt",
    "gt_format",
    "gt_scale",
    "gt_invalid",
    "width",
    "height",
];

/// Reads `DIR/PAIRS.tsv` (or the file itself when `path` names a file).
pub fn read_index(path: &Path) -> Result<Vec<PairRecord>> {
    let file = if path.is_dir() {
        path.join("PAIRS.tsv")
    } else {
        path.to_path_buf()
    };
    let text = crate::io::files::read_text(&file, "pair index")?;
    let root = file.parent().unwrap_or(Path::new("."));
    parse_index(&text, root).with_context(|| format!("pair index {}", file.display()))
}

/// Parses the text of a `PAIRS.tsv`, resolving paths against `root`. Lines end in LF (a CR LF
/// line is refused rather than read with a stray carriage return), every row has the
/// header's number of fields, and every path stays inside `root`.
pub fn parse_index(text: &str, root: &Path) -> Result<Vec<PairRecord>> {
    if let Some(number) = text.split('\n').position(|l| l.contains('\r')) {
        bail!(
            "line {} ends in CR LF or holds a carriage return (Windows line ends?): save the index with LF line ends",
            number + 1
        );
    }
    let mut lines = text.lines().enumerate().filter(|(_, l)| !l.trim().is_empty());
    let (_, header) = lines.next().context("empty index (no header line)")?;
    let names: Vec<&str> = header.split('\t').map(str::trim).collect();
    let mut index = [0usize; COLUMNS.len()];
    for (slot, column) in index.iter_mut().zip(COLUMNS) {
        *slot = names
            .iter()
            .position(|n| *n == column)
            .with_context(|| format!("header lacks column {column:?}"))?;
    }
    let mut records = Vec::new();
    for (number, line) in lines {
        let fields: Vec<&str> = line.split('\t').map(str::trim).collect();
        ensure!(
            fields.len() == names.len(),
            "line {}: {} tab-separated fields, the header has {}",
            number + 1,
            fields.len(),
            names.len()
        );
        let field = |i: usize| fields.get(index[i]).copied().unwrap_or("");
        let record = parse_record(&field, root).with_context(|| format!("line {}", number + 1))?;
        records.push(record);
    }
    let mut ids: Vec<&str> = records.iter().map(|r| r.pair_id.as_str()).collect();
    ids.sort_unstable();
    if let Some(w) = ids.windows(2).find(|w| w[0] == w[1]) {
        bail!("pair_id {:?} appears twice", w[0]);
    }
    Ok(records)
}

fn parse_record<'a>(field: &dyn Fn(usize) -> &'a str, root: &Path) -> Result<PairRecord> {
    let pair_id = field(0);
    ensure!(!pair_id.is_empty(), "empty pair_id");
    let split = match field(1) {
        "train" => Split::Train,
        "eval" => Split::Eval,
        "val" => Split::Val,
        other => bail!("pair {pair_id}: split {other:?} is none of train, eval, val"),
    };
    let path = |i: usize, what: &str| -> Result<PathBuf> {
        let value = field(i);
        ensure!(!value.is_empty(), "pair {pair_id}: no {what} image");
        inside(root, value).with_context(|| format!("pair {pair_id}: {what} image"))
    };
    let gt = match field(5) {
        "" => None,
        gt => {
            let format = GtFormat::from_name(field(6)).with_context(|| {
                let known: Vec<&str> = GtFormat::ALL.iter().map(|f| f.name()).collect();
                format!(
                    "pair {pair_id}: unknown gt_format {:?} (known: {})",
                    field(6),
                    known.join(", ")
                )
            })?;
            let scale: f32 = field(7)
                .parse()
                .with_context(|| format!("pair {pair_id}: bad gt_scale {:?}", field(7)))?;
            ensure!(
                scale.is_finite() && scale > 0.0,
                "pair {pair_id}: gt_scale must be positive and finite"
            );
            let invalid = parse_invalid(field(8), format)
                .with_context(|| format!("pair {pair_id}: bad gt_invalid {:?} for {format}", field(8)))?;
            Some(GroundTruth {
                path: inside(root, gt).with_context(|| format!("pair {pair_id}: ground truth"))?,
                format,
                scale,
                invalid,
            })
        }
    };
    ensure!(
        split == Split::Train || gt.is_some(),
        "pair {pair_id}: {split} pair without ground truth"
    );
    let size = |i: usize, what: &str| -> Result<usize> {
        field(i)
            .parse()
            .with_context(|| format!("pair {pair_id}: bad {what} {:?}", field(i)))
    };
    Ok(PairRecord {
        pair_id: pair_id.to_string(),
        split,
        dataset: field(2).to_string(),
        left: path(3, "left")?,
        right: path(4, "right")?,
        gt,
        width: size(9, "width")?,
        height: size(10, "height")?,
    })
}

/// The `gt_invalid` column: an integer within the format's range, or, for `pfm` only, empty.
fn parse_invalid(value: &str, format: GtFormat) -> Result<Option<u16>> {
    if value.is_empty() && format == GtFormat::Pfm {
        return Ok(None);
    }
    let invalid: u16 = value.parse().context("not a whole number from 0 to 65535")?;
    if let Some(max) = format.max_invalid() {
        ensure!(invalid <= max, "above {max}, the format's largest value");
    }
    Ok(Some(invalid))
}

/// `root/value`, refusing a `value` that is absolute or climbs out of `root` with `..`: an
/// index names files of its own folder only.
fn inside(root: &Path, value: &str) -> Result<PathBuf> {
    use std::path::Component;
    let relative = Path::new(value);
    let mut depth = 0usize;
    for component in relative.components() {
        match component {
            Component::Normal(_) => depth += 1,
            Component::CurDir => {}
            Component::ParentDir if depth > 0 => depth -= 1,
            _ => bail!("path {value:?} leaves the index's folder"),
        }
    }
    Ok(root.join(relative))
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER: &str = "pair_id\tsplit\tdataset\tleft\tright\tgt\tgt_format\tgt_scale\tgt_invalid\twidth\theight\n";

    #[test]
    fn parses_train_and_eval_rows() {
        let text = format!(
            "{HEADER}a\teval\tmb\tx/l.png\tx/r.png\tx/d.pgm\tpgm_u8\t8\t0\t432\t381\nb\ttrain\tk\tl.png\tr.png\t\t\t\t\t1344\t372\n"
        );
        let pairs = parse_index(&text, Path::new("/data")).unwrap();
        assert_eq!(pairs.len(), 2);
        assert_eq!(pairs[0].left, Path::new("/data/x/l.png"));
        assert_eq!(pairs[0].gt.as_ref().unwrap().scale, 8.0);
        assert_eq!(pairs[1].split, Split::Train);
        assert!(pairs[1].gt.is_none());
        assert_eq!((pairs[1].width, pairs[1].height), (1344, 372));
    }

    #[test]
    fn reports_bad_lines_by_number() {
        let text = format!("{HEADER}a\ttest\tmb\tl\tr\t\t\t\t\t4\t4\n");
        let err = format!("{:#}", parse_index(&text, Path::new(".")).unwrap_err());
        assert!(
            err.contains("line 2") && err.contains("none of train, eval, val"),
            "{err}"
        );
        let text = format!("{HEADER}a\teval\tmb\tl\tr\t\t\t\t\t4\t4\n");
        assert!(
            parse_index(&text, Path::new(".")).is_err(),
            "eval rows need ground truth"
        );
        let text = format!("{HEADER}a\ttrain\tk\tl\tr\t\t\t\t\t4\t4\na\ttrain\tk\tl\tr\t\t\t\t\t4\t4\n");
        assert!(parse_index(&text, Path::new(".")).is_err(), "duplicate ids");
        assert!(
            parse_index("pair_id\tsplit\n", Path::new(".")).is_err(),
            "missing columns"
        );
    }

    #[test]
    fn hostile_indexes_are_refused_with_the_line() {
        let err = |text: String| format!("{:#}", parse_index(&text, Path::new("/data")).unwrap_err());
        let row = "a\ttrain\tk\tl.png\tr.png\t\t\t\t\t4\t4";
        let e = err(format!("{HEADER}{row}\r\n"));
        assert!(e.contains("line 2 ends in CR LF"), "{e}");
        let e = err(format!("{HEADER}a\ttrain\tk\tl.png\tr.png\n"));
        assert!(e.contains("line 2: 5 tab-separated fields, the header has 11"), "{e}");
        for bad in ["../../etc/passwd", "/etc/passwd", "x/../../y.png"] {
            let e = err(format!("{HEADER}a\ttrain\tk\t{bad}\tr.png\t\t\t\t\t4\t4\n"));
            assert!(e.contains("leaves the index's folder"), "{bad}: {e}");
        }
        let e = err(format!(
            "{HEADER}a\teval\tk\tl.png\tr.png\t../gt.pgm\tpgm_u8\t1\t0\t4\t4\n"
        ));
        assert!(e.contains("ground truth") && e.contains("leaves"), "{e}");
        // Paths that stay inside, however spelled, are fine.
        let ok = format!("{HEADER}a\ttrain\tk\t./x/../l.png\tr.png\t\t\t\t\t4\t4\n");
        assert_eq!(
            parse_index(&ok, Path::new("/data")).unwrap()[0].left,
            Path::new("/data/./x/../l.png")
        );
    }

    #[test]
    fn every_gt_format_with_its_gt_invalid_rule() {
        let row = |format: &str, invalid: &str| {
            format!("{HEADER}a\teval\tk\tl.png\tr.png\td.x\t{format}\t256\t{invalid}\t4\t4\n")
        };
        let gt = |format: &str, invalid: &str| {
            let pairs = parse_index(&row(format, invalid), Path::new("/data")).map_err(|e| format!("{e:#}"));
            pairs.map(|p| p[0].gt.clone().unwrap())
        };
        for format in GtFormat::ALL {
            assert_eq!(gt(format.name(), "0").unwrap().format, format);
            assert_eq!(gt(format.name(), "0").unwrap().invalid, Some(0));
        }
        assert_eq!(gt("png_u16", "65535").unwrap().invalid, Some(65535));
        // Only a float format may leave gt_invalid empty: its unknowns are the non-finite values.
        assert_eq!(gt("pfm", "").unwrap().invalid, None);
        for (format, invalid, needle) in [
            ("png_u8", "", "bad gt_invalid \"\" for png_u8"),
            ("pgm_u8", "256", "above 255"),
            ("png_u16", "65536", "not a whole number"),
            ("png_u16", "-1", "not a whole number"),
            (
                "exr",
                "0",
                "unknown gt_format \"exr\" (known: pgm_u8, png_u8, png_u16, pfm)",
            ),
        ] {
            let e = gt(format, invalid).unwrap_err();
            assert!(e.contains("line 2") && e.contains(needle), "{format} {invalid}: {e}");
        }
        let e = format!(
            "{:#}",
            parse_index(&row("pfm", "").replace("\t256\t", "\tinf\t"), Path::new(".")).unwrap_err()
        );
        assert!(e.contains("gt_scale must be positive and finite"), "{e}");
    }
}
