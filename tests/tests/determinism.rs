//! Determinism (issue 12): the firmware's own workload (`firmware-sim/src/workload.rs`, the
//! shipped blob, the embedded 48x160 band pair on both pathways of the learned preset, the
//! embedded 160x120 frame through both presets, and the Alif E7's 320x240 frame through both
//! with the options of that width) gives bit-identical outputs run after run and on several
//! threads at once on the host, and the same digests the Cortex-M55 and Cortex-M7 firmwares
//! computed under QEMU (`firmware-sim/measured/*.json`, written by `scripts/firmware.sh
//! --profile --kernels --frame320 --out firmware-sim/measured`: only the M55 runs the E7 frame). The refined rows' digest is
//! also recomputed from the specification: the whole-map refinement the preset names
//! (`refine::sharpness::refine_map_equalised`, or `refine::refine_map` without equalisation) on
//! the whole token map the preset reads: the head and SGM fused by their checks (`lr::fuse_row`
//! through the host's `readout::fuse_grid`, export pathway), the head fused with the census SGM
//! (native), or the census SGM alone (the fast preset), filled.

mod firmware;

use bino_core::blob::Blob;
use bino_core::census;
use bino_core::crc32::Crc32;
use bino_core::lr::fill_background;
use bino_core::model::head::HeadRow;
use bino_core::pipeline::{HeadChecked, MatchedRow, Pipeline, RefineInput, Sink, SlicePair};
use bino_core::refine::sharpness::refine_map_equalised;
use bino_core::refine::{keep_rejected_map, refine_map, scratch_len};
use bino_host::readout::fuse_grid;
use bino_tests::census_whole_map;
use bino_tests::repo;
use firmware::workload::{self, Run, OUTPUTS};
use firmware::Quiet;

/// A committed pair the firmware embeds.
struct Pair {
    height: usize,
    width: usize,
    left: Vec<u8>,
    right: Vec<u8>,
}

impl Pair {
    /// `firmware-sim/assets/<kind>_<H>x<W>_{left,right}.gray`.
    fn read(kind: &str, height: usize, width: usize) -> Self {
        let assets = repo().join("firmware-sim/assets");
        let view = |v: &str| std::fs::read(assets.join(format!("{kind}_{height}x{width}_{v}.gray"))).unwrap();
        Self {
            height,
            width,
            left: view("left"),
            right: view("right"),
        }
    }

    /// What `run` reads: the 48x160 band for the learned preset's band pair, the 160x120 frame
    /// for the fast preset and the learned frame, the E7's frame for their runs on it.
    fn of(run: Run) -> Self {
        match run {
            Run::Export | Run::Native => Self::read("band", 48, 160),
            Run::Census | Run::Frame => Self::read("frame", 120, 160),
            Run::Census320 | Run::Frame320 => {
                let (height, width) = workload::E7_FRAME;
                Self::read("frame", height, width)
            }
        }
    }
}

/// The workload's digests of `run` on its committed pair, in a fresh arena of exactly the
/// firmware's size each time.
fn digests(blob: &[u8], run: Run, pair: &Pair) -> [u32; OUTPUTS.len()] {
    let (height, width) = (pair.height, pair.width);
    let mut arena = vec![0xA5u8; workload::run_arena_bytes(run, height, width)];
    let mut source = SlicePair::new(&pair.left, &pair.right, width, height).unwrap();
    workload::run(blob, run, &mut source, &mut arena, &mut Quiet)
        .unwrap()
        .digests
}

/// The digests a firmware run recorded: (pathway, output name, digest), in log order.
fn firmware_digests(core: &str) -> Vec<(String, String, u32)> {
    let path = repo().join(format!("firmware-sim/measured/{core}.json"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let run: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(run["band"]["width"], 160, "{}: the 48x160 band", path.display());
    assert_eq!(run["passed"], true, "{}", path.display());
    run["outputs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|o| {
            let pathway = o["pathway"].as_str().unwrap().to_string();
            let name = o["name"].as_str().unwrap().to_string();
            let digest = u32::from_str_radix(o["digest"].as_str().unwrap(), 16).unwrap();
            (pathway, name, digest)
        })
        .collect()
}

/// The head's rows and its check's masks of a run, and the SGM's, by token row.
struct HeadMaps {
    cols: usize,
    head: Vec<u16>,
    confidence: Vec<u16>,
    mask: Vec<u8>,
    sgm: Vec<u16>,
    sgm_mask: Vec<u8>,
}

impl Sink for HeadMaps {
    fn matched(&mut self, row: &MatchedRow<'_>) {
        let c = self.cols;
        self.sgm[row.row * c..(row.row + 1) * c].copy_from_slice(row.sgm_q8);
        self.sgm_mask[row.row * c..(row.row + 1) * c].copy_from_slice(row.sgm_consistent);
    }
    fn head(&mut self, row: HeadRow<'_>) {
        let c = self.cols;
        self.head[row.row * c..(row.row + 1) * c].copy_from_slice(row.disparity_q8);
        self.confidence[row.row * c..(row.row + 1) * c].copy_from_slice(row.confidence_q8);
    }
    fn head_checked(&mut self, row: &HeadChecked<'_>) {
        let c = self.cols;
        self.mask[row.row * c..(row.row + 1) * c].copy_from_slice(row.consistent);
    }
}

/// CRC-32 of the preset's whole-map refinement on the filled grid of `run` (fuse-all+lr on the
/// export pathway: the head fused with the census SGM computed over the whole map, that with
/// the SGM; fuse-census+lr on the native one: the head fused with the census SGM; census+lr for
/// the fast preset: the census SGM alone; rejected cells kept at the bilinear step) without the
/// refinement stage, rows top to bottom, values little-endian: what the workload's `refined`
/// digest must be.
fn refined_digest_from_the_whole_map(blob: &[u8], run: Run, pair: &Pair) -> u32 {
    let (height, width, left, right) = (pair.height, pair.width, &pair.left[..], &pair.right[..]);
    let (options, refine) = workload::preset(run);
    let want = match run {
        Run::Export => RefineInput::FusedAllLr,
        Run::Native | Run::Frame | Run::Frame320 => RefineInput::FusedCensusLr,
        Run::Census | Run::Census320 => RefineInput::CensusLr,
    };
    assert_eq!(refine.input, want);
    let cols = width / 4;
    let (census, census_mask) = census_whole_map(left, right, width, height, options.head_candidates);
    if matches!(run, Run::Census | Run::Census320) {
        return refined_crc(pair, census, &census_mask, &refine);
    }
    let pipeline = Pipeline::new(Blob::parse(blob).unwrap()).unwrap();
    let cells = height / 4 * cols;
    let mut maps = HeadMaps {
        cols,
        head: vec![0; cells],
        confidence: vec![0; cells],
        mask: vec![0; cells],
        sgm: vec![0; cells],
        sgm_mask: vec![0; cells],
    };
    let mut arena = vec![0u8; bino_core::pipeline::arena_bytes_for(height, width, &options)];
    let mut source = SlicePair::new(left, right, width, height).unwrap();
    pipeline.run(&mut source, &options, &mut arena, &mut maps).unwrap();
    let head = (&maps.head[..], &maps.mask[..]);
    let with_census = (&census[..], &census_mask[..]);
    let (first, first_mask) = fuse_grid(head, &maps.confidence, with_census, cols, census::FUSE_HEAD_WEIGHT).unwrap();
    let (grid, mask) = match run {
        Run::Export => {
            let sgm = (&maps.sgm[..], &maps.sgm_mask[..]);
            let first = (&first[..], &first_mask[..]);
            fuse_grid(first, &maps.confidence, sgm, cols, census::FUSE_ALL_FIRST_WEIGHT).unwrap()
        }
        Run::Native | Run::Frame | Run::Frame320 | Run::Census | Run::Census320 => (first, first_mask),
    };
    refined_crc(pair, grid, &mask, &refine)
}

/// CRC-32 of the whole-map refinement of `grid` (its rejected cells filled from the background,
/// as every preset's readout has the census in it, then kept at the bilinear step) on `pair`.
fn refined_crc(pair: &Pair, mut grid: Vec<u16>, mask: &[u8], refine: &bino_core::pipeline::Refine) -> u32 {
    let (width, height, left, right) = (pair.width, pair.height, &pair.left[..], &pair.right[..]);
    let cols = width / 4;
    for (row, m) in grid.chunks_exact_mut(cols).zip(mask.chunks_exact(cols)) {
        fill_background(row, m).unwrap();
    }
    let mut scratch = vec![0u32; scratch_len(width, &refine.params)];
    let mut refined = vec![0u16; width * height];
    let whole = if refine.equalise {
        refine_map_equalised
    } else {
        refine_map
    };
    whole(left, right, width, &grid, &refine.params, &mut scratch, &mut refined).unwrap();
    keep_rejected_map(width, &grid, mask, &mut refined).unwrap();
    let mut crc = Crc32::new();
    for v in refined {
        crc.update(&v.to_le_bytes());
    }
    crc.finish()
}

#[test]
fn outputs_are_bit_identical_across_runs_threads_and_targets() {
    let blob = std::fs::read(repo().join("weights/bino_int8.bin")).unwrap();
    let refined = OUTPUTS.iter().position(|&n| n == "refined").unwrap();
    let mut host = Vec::new();
    for run in Run::ALL {
        let pair = Pair::of(run);
        let first = digests(&blob, run, &pair);
        assert_eq!(
            first[refined],
            refined_digest_from_the_whole_map(&blob, run, &pair),
            "{run:?}: the streamed refinement against the whole map's"
        );
        assert_eq!(digests(&blob, run, &pair), first, "{run:?}: a second run on the host");
        let threads: Vec<[u32; OUTPUTS.len()]> = std::thread::scope(|scope| {
            let handles: Vec<_> = (0..3).map(|_| scope.spawn(|| digests(&blob, run, &pair))).collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        for (i, d) in threads.iter().enumerate() {
            assert_eq!(d, &first, "{run:?}: thread {i} of three running at once");
        }
        // x86 hosts: the AVX2 kernels and the portable ones (chosen at run time) give what the
        // AVX-512 VNNI ones do (where the CPU has them; else those runs take what it has).
        #[cfg(target_arch = "x86_64")]
        {
            use bino_core::kernels::dispatch::{active, limit, Isa};
            let fastest = active();
            for cap in [Isa::Avx2, Isa::Portable] {
                let ran = limit(cap);
                let capped = digests(&blob, run, &pair);
                assert_eq!(
                    capped,
                    first,
                    "{run:?}: {} kernels against {}",
                    ran.name(),
                    fastest.name()
                );
            }
            limit(fastest);
        }
        for &slot in workload::outputs(run) {
            host.push((run, OUTPUTS[slot].to_string(), first[slot]));
        }
    }
    // The M55's measurement runs the E7 frame too (--frame320); the M7's does not.
    for (core, e7) in [("m55", true), ("m7", false)] {
        let recorded = firmware_digests(core);
        let host: Vec<_> = host.iter().filter(|(run, ..)| e7 || !run.on_e7_frame()).collect();
        let names: Vec<(&str, &str)> = recorded.iter().map(|(p, n, _)| (p.as_str(), n.as_str())).collect();
        let want: Vec<(&str, &str)> = host.iter().map(|(r, n, _)| (r.name(), n.as_str())).collect();
        assert_eq!(names, want, "{core}: the workload's outputs, every run");
        for ((pathway, name, digest), (_, _, host)) in recorded.iter().zip(host) {
            assert_eq!(
                digest, host,
                "{core} {pathway} {name}: firmware {digest:08x}, host {host:08x} (re-measure with scripts/firmware.sh --profile --kernels --frame320 --out firmware-sim/measured after changing the blob or the engine)"
            );
        }
    }
}
