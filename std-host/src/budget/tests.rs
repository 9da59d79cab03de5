//! `bino budget`'s tests: firmware runs as JSON, a minimal ELF, and what the reports make of them.

use serde_json::{json, Value};

use super::*;

/// A minimal 32-bit little-endian ELF with the given sections (names and sizes only).
fn tiny_elf(sections: &[(&str, u32)]) -> Vec<u8> {
    let mut names = vec![0u8];
    let mut name_at = Vec::new();
    for (n, _) in sections.iter().chain([(".shstrtab", 0)].iter()) {
        name_at.push(names.len() as u32);
        names.extend_from_slice(n.as_bytes());
        names.push(0);
    }
    let shoff = 52 + names.len();
    let shnum = sections.len() + 2;
    let mut elf = vec![0u8; 52];
    elf[..7].copy_from_slice(b"\x7fELF\x01\x01\x01"); // 32-bit, little-endian, version 1
    elf[0x20..0x24].copy_from_slice(&(shoff as u32).to_le_bytes());
    elf[0x2E..0x30].copy_from_slice(&40u16.to_le_bytes());
    elf[0x30..0x32].copy_from_slice(&(shnum as u16).to_le_bytes());
    elf[0x32..0x34].copy_from_slice(&((shnum - 1) as u16).to_le_bytes());
    elf.extend_from_slice(&names);
    elf.extend_from_slice(&[0u8; 40]); // the null section
    for (i, (_, size)) in sections
        .iter()
        .chain([(".shstrtab", names.len() as u32)].iter())
        .enumerate()
    {
        let mut h = [0u8; 40];
        h[..4].copy_from_slice(&name_at[i].to_le_bytes());
        h[16..20].copy_from_slice(&(if i == sections.len() { 52u32 } else { 0 }).to_le_bytes());
        h[20..24].copy_from_slice(&size.to_le_bytes());
        elf.extend_from_slice(&h);
    }
    elf
}

#[test]
fn elf_section_headers_are_read() {
    let elf = tiny_elf(&[(".text", 43756), (".weights", 1537200), (".uninit", 486928)]);
    let got = elf_sections(&elf).unwrap();
    assert_eq!(
        got,
        vec![
            (".text".to_string(), 43756),
            (".weights".to_string(), 1537200),
            (".uninit".to_string(), 486928),
            (".shstrtab".to_string(), 34),
        ]
    );
    assert!(elf_sections(b"not an elf").is_err());
    assert!(
        elf_sections(&elf[..60]).is_err(),
        "truncated headers are an error, not a panic"
    );
}

#[test]
fn sections_are_grouped_into_flash_and_ram() {
    let s = Sections::from_named(
        [
            (".vector_table", 100),
            (".text", 1000),
            (".rodata", 50),
            (".data", 4),
            (".bss", 16),
        ]
        .map(|(n, v)| (n.to_string(), v)),
    );
    assert_eq!((s.code, s.code_flash(), s.bss, s.weights), (1150, 1154, 16, 0));
}

fn run_json(core: &str, encode: u64) -> String {
    json!({
        "schema": "bino-firmware-run/1", "core": core, "cpu": "cpu", "board": "board",
        "band": {"height": 48, "width": 160}, "passed": true, "qemu_wall_seconds": 10.0,
        "elf": "/nonexistent/bino-firmware",
        "elf_sections": {".text": {"size": 40000, "addr": 0}, ".rodata": {"size": 2000, "addr": 0},
                         ".data": {"size": 4, "addr": 0}, ".bss": {"size": 16, "addr": 0},
                         ".uninit": {"size": 486928, "addr": 0}, ".weights": {"size": 1537200, "addr": 0}},
        "arena_bytes": 486918, "arena_used": 486912, "stack_bytes": 32768,
        "arena_breakdown": {"pixels": 15360, "refine": 6881},
        "stages": [
            {"name": "load", "instructions": 8_000_000u64, "arena_in_use": 0, "stack_peak": 1784},
            {"name": "encode_left", "instructions": encode, "arena_in_use": 486912, "stack_peak": 7360},
            {"name": "head", "instructions": 100u64, "arena_in_use": 369256, "stack_peak": 6852},
            {"name": "refine", "instructions": 60_000_000u64, "arena_in_use": 300000, "stack_peak": 2000},
        ],
        "startup_instructions": 5, "outside_instructions": 7,
    })
    .to_string()
}

#[test]
fn runs_parse_and_add_up() {
    let r = CoreRun::parse(&run_json("m55", 700_000_000)).unwrap();
    assert_eq!(r.section_source, SectionSource::Recorded);
    assert_eq!(
        r.band_pair_instructions(),
        760_000_100,
        "load is a boot cost, not per band pair"
    );
    assert_eq!(r.refine_arena, Some(6881));
    assert_eq!(r.stage_instructions("refine"), Some(60_000_000));
    assert_eq!((r.stack_peak(), r.arena_high_water()), (7360, 486912));
    assert_eq!(r.ram_reserved(), 4 + 16 + 486928 + 32768);
    assert_eq!(r.ram_used(), 4 + 16 + 486912 + 7360);
    assert!(CoreRun::parse("{}").is_err());
    assert!(CoreRun::parse(&run_json("m55", 1).replace("bino-firmware-run/1", "other")).is_err());
}

/// `run_json` with class counts on every stage: all its instructions `other`, plus the
/// given adjustments.
fn run_json_with_classes(core: &str, encode: u64, adjustments: Value) -> String {
    let mut v: Value = serde_json::from_str(&run_json(core, encode)).unwrap();
    for stage in v["stages"].as_array_mut().unwrap() {
        let n = stage["instructions"].as_u64().unwrap();
        stage["classes"] = json!({"mve": 0, "fp": 0, "mul": 0, "div": 0, "load_store": 0,
                                  "branch": 0, "loop": 0, "other": n});
        stage["cycle_adjustments"] = adjustments.clone();
    }
    v.to_string()
}

#[test]
fn class_counts_are_optional_checked_and_priced() {
    let old = CoreRun::parse(&run_json("m7", 1000)).unwrap();
    assert!(!old.has_class_counts());
    assert_eq!(old.band_pair_modelled_cycles(), None);
    assert!(markdown(&[old]).contains("M7: no class counts in this run"));

    let adj = json!({"mve_overlap": 0, "dual_issue_pair": 100, "extra_words": 10});
    let r = CoreRun::parse(&run_json_with_classes("m7", 1000, adj.clone())).unwrap();
    assert!(r.has_class_counts());
    // encode_left: 1000 `other` at 1, 100 pairs at -0.5, 10 extra words at 0.5.
    assert_eq!(r.stages[1].modelled_cycles("m7"), Some(1000.0 - 50.0 + 5.0));
    // Band pair: encode_left, head (100), refine (60M), each with the same adjustments.
    assert_eq!(
        r.band_pair_modelled_cycles(),
        Some((1000 + 100 + 60_000_000) as f64 + 3.0 * (-50.0 + 5.0))
    );
    let md = markdown(std::slice::from_ref(&r));
    assert!(md.contains("a model, not a measurement"), "{md}");
    assert!(md.contains("| encode_left | 0.0 | 955 | 0.0 | 0.95 |"), "{md}");
    assert!(md.contains("| dual_issue_pair | 300 | -0.5 |"), "{md}");
    let j = to_json(std::slice::from_ref(&r)).unwrap();
    let cm = j.cores[0].cycle_model.as_ref().unwrap();
    assert_eq!(cm.class_counts["other"], 1000 + 100 + 60_000_000);
    assert_eq!(j.cores[0].stages[1].modelled_cycles, Some(955.0));

    let mut bad: Value = serde_json::from_str(&run_json_with_classes("m55", 1000, adj)).unwrap();
    bad["stages"][1]["classes"]["other"] = json!(999);
    let err = format!("{:#}", CoreRun::parse(&bad.to_string()).unwrap_err());
    assert!(err.contains("encode_left") && err.contains("add up to 999"), "{err}");
    bad["stages"][1]["classes"]["other"] = json!(1000);
    bad["stages"][1]["cycle_adjustments"]["warp"] = json!(1);
    let err = format!("{:#}", CoreRun::parse(&bad.to_string()).unwrap_err());
    assert!(err.contains("\"warp\" has no cost"), "{err}");
}

#[test]
fn the_elf_is_read_only_when_it_is_the_one_measured() {
    let dir = std::env::temp_dir().join(format!("bino-budget-elf-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bino-firmware");
    let elf = tiny_elf(&[(".text", 1000), (".weights", 77), (".uninit", 5)]);
    std::fs::write(&path, &elf).unwrap();
    let with = |sha: &str| {
        let mut v: Value = serde_json::from_str(&run_json("m55", 1)).unwrap();
        v["elf"] = json!(path.to_str().unwrap());
        v["elf_sha256"] = json!(sha);
        CoreRun::parse(&v.to_string()).unwrap()
    };
    let same = with(&crate::io::files::sha256_hex(&elf));
    assert_eq!(same.section_source, SectionSource::Elf(path.clone()));
    assert_eq!(
        (same.sections.code, same.sections.weights, same.sections.uninit),
        (1000, 77, 5)
    );
    let rebuilt = with("0000");
    assert_eq!(rebuilt.section_source, SectionSource::Recorded);
    assert_eq!(rebuilt.sections.weights, 1537200, "the sizes recorded at the run");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn verdicts_judge_the_targets() {
    let m55 = CoreRun::parse(&run_json("m55", 680_000_000)).unwrap();
    let m7 = CoreRun::parse(&run_json("m7", 4_740_000_000)).unwrap();
    let v = verdicts(&[m55.clone(), m7]);
    let met: Vec<bool> = v.iter().map(|v| v.met).collect();
    // weights 1,537,200 B <= 1.5 MiB, and the learned preset's (the checkout's native-only
    // blob); arena 486,918 <= 512 KiB; M55 740M <= 800M and its refinement 60M of a 680M pass
    // (8.8 %); M7 10 s > 8 s and 60M of 4740M; the export ceilings: 740M <= 1.3G, 4.8G <= 8G.
    assert_eq!(met, [true, true, true, true, true, false, true, true, true], "{v:#?}");
    assert!(v[1].target.contains("learned preset"), "{}", v[1].target);
    let native_blob = std::fs::metadata(crate::io::checkout::path(crate::io::checkout::NATIVE_BLOB)).unwrap();
    assert_eq!(v[1].measured, format!("{:.1} KiB", native_blob.len() as f64 / 1024.0));
    assert!(v[7].measured.ends_with("(under by 560.0M)"), "{}", v[7].measured);
    assert!(v[4].measured.starts_with("60.0M (8.82 %"), "{}", v[4].measured);
    assert!(v[5].measured.starts_with("10.00 s"), "{}", v[5].measured);
    let slow = CoreRun::parse(&run_json("m55", 500_000_000)).unwrap();
    let v = verdicts(&[slow]);
    assert!(v[3].met && !v[4].met, "{v:#?}: 60M is 12 % of a 500M pass");
    assert!((clock("m55").ms(400_000_000) - 1000.0).abs() < 1e-9);
    assert!((clock("m7").ms(480_000_000) - 1000.0).abs() < 1e-9);
}

/// A firmware that runs both pathways: the native stages (`native_*`) stay out of the export
/// band pair, stages never entered are dropped, and the native band pair (its check read from
/// the same pass) is judged against the export one, met and missed.
#[test]
fn the_native_pathway_is_judged_beside_the_export_one() {
    let native_verdict = |refine: u64| {
        let mut v: Value = serde_json::from_str(&run_json("m55", 700_000_000)).unwrap();
        let stages = v["stages"].as_array_mut().unwrap();
        for (name, n) in [
            ("encode_pair", 0u64),
            ("native_encode_pair", 300_000_000),
            ("native_head", 50),
            ("native_refine", refine),
        ] {
            stages.push(json!({"name": name, "instructions": n, "arena_in_use": 1, "stack_peak": 1}));
        }
        let r = CoreRun::parse(&v.to_string()).unwrap();
        assert!(r.stage_instructions("encode_pair").is_none(), "never entered: dropped");
        assert_eq!(r.band_pair_instructions(), 760_000_100, "the export pathway alone");
        assert_eq!(r.native_band_pair_instructions(), Some(300_000_050 + refine));
        let all = verdicts(std::slice::from_ref(&r));
        let verdict = all
            .iter()
            .find(|v| v.target.contains("native band pair"))
            .unwrap()
            .clone();
        // The time target judges the board's pathway: the native band pair.
        let time = all
            .iter()
            .find(|v| v.target.contains("per band pair, the board's native pathway"));
        let native = r.native_band_pair_instructions().unwrap();
        assert_eq!(
            time.map(|v| (v.met, v.measured.clone())),
            Some((
                native <= 800_000_000,
                format!(
                    "{:.0}M ({:.1}x the target; {:.2} s)",
                    native as f64 / 1e6,
                    native as f64 / 8e8,
                    native as f64 / 4e8
                )
            )),
            "{all:#?}"
        );
        (r, verdict)
    };
    // 360M of 760M: 47.4 % <= 55 %.
    let (r, verdict) = native_verdict(60_000_000);
    assert!(verdict.met, "{verdict:?}");
    assert!(
        verdict.measured.starts_with("360M (47.4 % of 760M"),
        "{}",
        verdict.measured
    );
    let md = markdown(std::slice::from_ref(&r));
    assert!(
        md.contains("| **band pair, native pathway** (native_*) | | | **360,000,050** |"),
        "{md}"
    );
    // 440M of 760M: 57.9 % > 55 %.
    let (_, verdict) = native_verdict(140_000_000);
    assert!(!verdict.met, "{verdict:?}");
    assert!(CoreRun::parse(&run_json("m55", 1))
        .unwrap()
        .native_band_pair_instructions()
        .is_none());
}

#[test]
fn markdown_and_json_carry_the_numbers() {
    let runs = [CoreRun::parse(&run_json("m55", 700_000_000)).unwrap()];
    let md = markdown(&runs);
    assert!(md.contains("| weights flash (`.weights`) | 1,537,200 B |"), "{md}");
    assert!(
        md.contains("| of which the refinement (`pipeline::refine_bytes`) | 6,881 B |"),
        "{md}"
    );
    assert!(
        md.contains("| refine | 300,000 B | 2,000 B | 60,000,000 | 150.0 |"),
        "{md}"
    );
    assert!(
        md.contains("| encode_left | 486,912 B | 7,360 B | 700,000,000 | 1750.0 |"),
        "{md}"
    );
    assert!(md.contains("not cycles"), "{md}");
    let j = to_json(&runs).unwrap();
    assert_eq!(j.cores[0].band_pair_instructions, 760_000_100);
    assert_eq!(j.cores[0].refine_arena_bytes, Some(6881));
    assert_eq!(j.cores[0].assumed_instructions_per_cycle, 1.0);
    let text = serde_json::to_string_pretty(&j).unwrap();
    let v: Value = serde_json::from_str(&text).unwrap();
    assert_eq!(v["cores"][0]["band_pair_instructions"], 760_000_100u64);
    assert_eq!(v["cores"][0]["stages"][3]["name"], "refine");
    assert_eq!(v["targets"][0]["met"], true);
    assert_eq!(v["schema"], "bino-budget/1");
    // Keys sorted at every level, as the file always had them (`Value` maps are sorted).
    assert_eq!(text, serde_json::to_string_pretty(&v).unwrap());
    assert_eq!(grouped(1234567), "1,234,567");
    assert_eq!(grouped(12), "12");
}

#[test]
fn the_chart_draws_bars_and_text() {
    let runs = [
        CoreRun::parse(&run_json("m55", 700_000_000)).unwrap(),
        CoreRun::parse(&run_json("m7", 4_740_000_000)).unwrap(),
    ];
    let chart = chart::draw(&runs).unwrap();
    assert_eq!(chart.dimensions(), chart::SIZE);
    let count = |f: &dyn Fn(&image::Rgb<u8>) -> bool| chart.pixels().filter(|p| f(p)).count();
    // The two series' colours: blue bars (arena, M55) and orange ones (stack, M7).
    let blue = count(&|p| p.0 == [33, 150, 228]);
    let orange = count(&|p| p.0 == [245, 124, 32]);
    assert!(
        blue > 5_000 && orange > 5_000,
        "{blue} blue, {orange} orange bar pixels"
    );
    // Text (titles, stage names, value labels) is dark and anti-aliased: many grey levels.
    let dark = count(&|p| p.0.iter().all(|&c| c < 100));
    let greys: std::collections::BTreeSet<u8> = chart
        .pixels()
        .filter(|p| p.0[0] == p.0[1] && p.0[1] == p.0[2])
        .map(|p| p.0[0])
        .collect();
    assert!(
        dark > 5_000,
        "{dark} dark pixels: no text drawn? (the axes alone are about 2,300)"
    );
    assert!(greys.len() > 50, "{} grey levels: text not anti-aliased", greys.len());
    // The caption strip above the first panel holds its title.
    let title = (0..25).flat_map(|y| (0..chart::SIZE.0).map(move |x| (x, y)));
    let title_ink = title.filter(|&(x, y)| chart.get_pixel(x, y).0[0] < 128).count();
    assert!(title_ink > 600, "{title_ink} title pixels");
}

/// A synthetic run at 48x160: the frame rule is exact arithmetic on it.
fn frame_run() -> CoreRun {
    CoreRun::parse(&frame_run_json()).unwrap()
}

/// `frame_run`'s JSON.
fn frame_run_json() -> String {
    let mut v: Value = serde_json::from_str(&run_json("m55", 1_000_000_000)).unwrap();
    let stages = v["stages"].as_array_mut().unwrap();
    for (name, n) in [
        ("match", 520_000u64),
        ("native_head", 4_000_000),
        ("native_encode_pair", 2_000_000_000),
    ] {
        stages.push(json!({"name": name, "instructions": n, "arena_in_use": 1, "stack_peak": 1}));
    }
    v.to_string()
}

#[test]
fn frames_scale_each_stage_by_its_work() {
    use crate::bench::encoder_macs;
    use frame::{pairs, scale, Pathway, Scaling};
    let run = frame_run();
    let by_name = |pathway, f: Frame| -> std::collections::BTreeMap<String, f64> {
        scale(&run, pathway, f)
            .unwrap()
            .into_iter()
            .map(|s| (s.name, s.instructions))
            .collect()
    };
    // The measured band itself: every stage as measured, load left out.
    let same = by_name(Pathway::Export, Frame::new(48, 160));
    assert_eq!(same["encode_left"], 1e9);
    assert!(!same.contains_key("load") && !same.contains_key("native_head"));

    // 320x240: 60 token rows of 80 cells against 12 of 40; seven bands of 12 token rows.
    let f = Frame::new(240, 320);
    assert_eq!(f.plan().unwrap().len(), 7);
    let got = by_name(Pathway::Export, f);
    // A per-cell stage is exactly linear: (80 / 40) x (60 / 12) = 10 times; the head reads
    // each band's 12 rows: (80 / 40) x (7 x 12 / 12) = 14 times.
    assert_eq!(got["refine"], 60e6 * 10.0);
    assert_eq!(got["head"], 100.0 * 14.0);
    // The encoder follows encoder_macs over the token rows each band encodes (x 160 fused
    // columns) against 12 x 80: with the shipped blob's shared rows the 60 rows once each,
    // else seven whole bands.
    let span = frame::shipped_span();
    let encoded: Vec<usize> = frame::encoded_rows(&f.plan().unwrap()).collect();
    let shared = encoded.iter().sum::<usize>() == 60;
    assert!(shared || encoded == [12; 7], "{encoded:?}");
    let macs = |rows| encoder_macs(rows, 160, span) as f64 / encoder_macs(12, 80, span) as f64;
    let want = 1e9 * encoded.iter().map(|&rows| macs(rows)).sum::<f64>();
    assert!(
        (got["encode_left"] - want).abs() < 1e-3,
        "{} vs {want}",
        got["encode_left"]
    );
    assert!(macs(12) > 2.0, "attention grows faster than the width");
    // The matcher: 16 candidates, fewer in the first 15 columns.
    assert_eq!((pairs(40, 16), pairs(80, 16), pairs(8, 16)), (520, 1160, 36));
    assert!((got["match"] - 520_000.0 * 5.0 * 1160.0 / 520.0).abs() < 1e-6);
    let native = by_name(Pathway::Native, f);
    // Each band's head reads its own 12 rows (those it keeps and 6 around them), on either
    // pathway: 7 x 12 rows of 80 cells against 12 of 40.
    assert_eq!(Scaling::of("native_head"), Scaling::HeadRows);
    assert_eq!(Scaling::of("head"), Scaling::HeadRows);
    assert_eq!(Scaling::of("sgm"), Scaling::Cells);
    assert_eq!(native["native_head"], 4e6 * 2.0 * (7.0 * 12.0) / 12.0);
    assert!((native["native_encode_pair"] - 2.0 * want).abs() < 1e-3);
    assert_eq!(Scaling::of("load"), Scaling::Boot);
    assert_eq!(Scaling::of("native_encode_pair"), Scaling::Encoder);

    // A fit through two widths is exact at both and linear in the work between.
    let (a, b) = (Frame::new(48, 160), Frame::new(48, 32));
    let cells = Scaling::Cells;
    // 1000 per token row plus 10 per cell: 12 x (1000 + 400) at 160 px, 12 x (1000 + 80) at 32.
    let fit = |to| cells.fitted((a, 16_800), (b, 12_960), to).unwrap().unwrap();
    assert!((fit(a) - 16_800.0).abs() < 1e-6 && (fit(b) - 12_960.0).abs() < 1e-6);
    assert!((fit(Frame::new(240, 320)) - 60.0 * (1000.0 + 800.0)).abs() < 1e-6);
}

#[test]
fn frame_budgets_carry_time_fps_and_the_exact_arena() {
    let run = frame_run();
    let frames = FramesReport::new(
        std::slice::from_ref(&run),
        &[],
        &FrameOptions {
            frames: vec![Frame::new(120, 160)],
            clock_mhz: Some(100.0),
        },
    )
    .unwrap();
    assert!(frames.scaling_check.is_empty());
    let [export, native] = &frames.estimates[..] else {
        panic!("{:?}", frames.estimates)
    };
    assert_eq!((export.bands, export.clock_mhz), (4, 100.0));
    assert_eq!(
        export.arena_bytes,
        bino_core::preset::export_arena_bytes(120, 160) as u64
    );
    assert_eq!(native.arena_bytes, bino_core::preset::arena_bytes(120, 160) as u64);
    // Rounded to a millionth.
    assert!((export.seconds_ipc1 - export.instructions as f64 / 100e6).abs() <= 5e-7);
    assert!((export.frames_per_s_ipc1 * export.seconds_ipc1 - 1.0).abs() < 1e-5);
    assert_eq!(export.modelled_seconds, None, "no class counts in this run");
    let md = frames_markdown(std::slice::from_ref(&run), &frames);
    assert!(md.contains("| 160x120 | 4 | M55 at 100 MHz | export |"), "{md}");
    assert!(md.contains("not checked here"), "{md}");

    // Parsing: WxH, on the pipeline's grid.
    assert_eq!("320x240".parse::<Frame>().unwrap(), Frame::new(240, 320));
    for (bad, why) in [
        ("640x", "expected WxH"),
        ("x480", "expected WxH"),
        ("640", "expected WxH"),
        ("642x480", "width 642 is not a multiple of 4"),
        ("640x482", "height 482 is not a multiple of 4"),
        ("0x480", "zero rows or columns"),
        ("640x100000", "exceeds the maximum"),
    ] {
        let err = format!("{:#}", bad.parse::<Frame>().unwrap_err());
        assert!(err.contains(why), "{bad}: {err}");
        assert!(!err.contains('\n'), "{bad}: one line: {err}");
    }
}

#[test]
fn the_scaling_check_compares_a_run_with_its_second_width() {
    let run = frame_run();
    let mut v: Value = serde_json::from_str(&run_json("m55", 110_000_000)).unwrap();
    v["band"]["width"] = json!(32);
    let small = CoreRun::parse(&v.to_string()).unwrap();
    let c = frame::check(&run, &small).unwrap();
    let head = c.stages.iter().find(|s| s.name == "head").unwrap();
    // 100 at 160 px scaled to 32 px: 20, measured 100: -80 %.
    assert_eq!((head.predicted, head.measured), (20, 100));
    assert!((head.error_percent + 80.0).abs() < 1e-9);
    assert!(c.stages.iter().any(|s| s.name == "band pair, export"));
    assert!(
        !c.stages.iter().any(|s| s.name == "native_head"),
        "the small run lacks it"
    );
    let frames = FramesReport::new(
        std::slice::from_ref(&run),
        std::slice::from_ref(&small),
        &FrameOptions::default(),
    )
    .unwrap();
    assert_eq!(frames.scaling_check.len(), 1);
    assert!(frames.estimates.iter().all(|e| e.fitted_instructions.is_some()));
    let md = frames_markdown(std::slice::from_ref(&run), &frames);
    assert!(md.contains("the 48x160 band pair scaled to 48x32"), "{md}");
    assert!(
        md.contains("| head | head rows per band x cells | 20 | 100 | -80.0 % |"),
        "{md}"
    );
}

/// The chart's stage names and pathway captions, as laid out for the committed runs' stages,
/// do not overlap on any row, measured in the chart's font and with a conservative 8 px a
/// character.
#[test]
fn chart_labels_do_not_overlap() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../firmware-sim/measured");
    let runs = load_runs(&dir).unwrap();
    let stages: Vec<String> = (chart::charted_stages(&runs[0]).iter())
        .map(|s| s.name.clone())
        .collect();
    assert!(stages.len() >= 13, "{stages:?}");
    assert!(
        !stages.iter().any(|s| s.contains("320") || s.starts_with(FRAME_PREFIX)),
        "{stages:?}"
    );
    // The plot spans the chart less its margins (10 px) and the y labels (60 px).
    let span = (70, chart::SIZE.0 as i32 - 10);
    let font = |t: &str| chart::text_width(t);
    let conservative = |t: &str| 8 * t.chars().count() as i32;
    for measure in [&font as &dyn Fn(&str) -> i32, &conservative] {
        let placed = chart::x_label_layout(&stages, span, measure);
        for row in 0..3 {
            let mut boxes: Vec<&chart::Placed> = placed.iter().filter(|p| p.row == row).collect();
            boxes.sort_by_key(|p| p.left);
            for pair in boxes.windows(2) {
                assert!(
                    pair[0].left + pair[0].width + chart::LABEL_GAP <= pair[1].left,
                    "row {row}: {:?} and {:?} overlap",
                    pair[0],
                    pair[1]
                );
            }
            for b in &boxes {
                assert!(
                    b.left >= span.0 - 35 && b.left + b.width <= span.1 + 10,
                    "{b:?} off the chart"
                );
            }
        }
    }
    assert_eq!(chart::stage_label("native_encode_pair"), ["encode", "pair"]);
    assert_eq!(chart::stage_label("head"), ["head"]);
    assert_eq!(chart::stage_label("census_refine"), ["refine"]);
    let groups = chart::groups(&stages);
    assert_eq!(groups.last().map(|g| g.0), Some("census frame"), "{groups:?}");
}

/// `frame_run` with the fast preset's whole 160x120 frame: its three stages and its section.
fn run_with_census(sgm: u64) -> CoreRun {
    let mut v: Value = serde_json::from_str(&frame_run_json()).unwrap();
    let stages = v["stages"].as_array_mut().unwrap();
    for (name, n, stack) in [
        ("census_rows", 100_000u64, 900u64),
        ("census_sgm", sgm, 6000),
        ("census_refine", 50_000_000, 11_000),
    ] {
        stages.push(json!({"name": name, "instructions": n, "arena_in_use": 1, "stack_peak": stack}));
    }
    v["census"] = json!({"frame": {"height": 120, "width": 160}, "arena_bytes": 70177, "arena_used": 70176,
                         "frame_instructions": 100_000 + sgm + 50_000_000, "stack_peak": 11_000});
    CoreRun::parse(&v.to_string()).unwrap()
}

#[test]
fn the_fast_preset_is_its_measured_frame_beside_the_learned_one() {
    use presets::{Preset, Source};
    let run = run_with_census(30_000_000);
    // The census run is neither pathway's band pair.
    assert_eq!(run.band_pair_instructions(), frame_run().band_pair_instructions());
    assert!(!frame::Pathway::Export.has("census_sgm") && !frame::Pathway::Native.has("census_sgm"));
    let opts = FrameOptions::default();
    let runs = std::slice::from_ref(&run);
    let frames = FramesReport::new(runs, &[], &opts).unwrap();
    let presets = PresetsReport::new(runs, &frames, &opts.frames).unwrap();
    let find = |preset, w| {
        presets
            .frames
            .iter()
            .find(|p| p.preset == preset && p.frame.width == w)
            .unwrap()
    };
    let fast = find(Preset::Fast, 160);
    assert_eq!((fast.instructions, fast.source), (80_100_000, Source::MeasuredFrame));
    assert_eq!(fast.arena_bytes, bino_core::preset::census_arena_bytes(120, 160) as u64);
    assert_eq!((fast.stack_peak_bytes, fast.frames_per_s_ipc1), (11_000, 4.993758));
    // 320x240: 60 token rows of 80 cells against 30 of 40, four times the work.
    let big = find(Preset::Fast, 320);
    assert_eq!((big.instructions, big.source), (320_400_000, Source::ScaledFrame));
    // The arena is the preset's as the board runs it at that width (16 candidates).
    let e7_arena = bino_core::preset::census_arena_bytes_for_width(240, 320) as u64;
    assert_eq!(big.arena_bytes, e7_arena);
    assert!(e7_arena > bino_core::preset::census_arena_bytes(240, 320) as u64);
    let learned = find(Preset::Learned, 160);
    let native = frames
        .estimates
        .iter()
        .find(|e| e.pathway == frame::Pathway::Native && e.frame.width == 160)
        .unwrap();
    assert_eq!(
        (learned.instructions, learned.source),
        (native.instructions, Source::ScaledBandPair)
    );
    assert_eq!(learned.arena_bytes, bino_core::preset::arena_bytes(120, 160) as u64);
    let md = presets_markdown(&presets);
    assert!(
        md.contains("| 160x120 | M55 at 400 MHz | fast | `census+lr+ref` | 80,100,000 | measured frame | 4.99 |"),
        "{md}"
    );
    // The target: at most 100M instructions per 160x120 frame at 400 MHz.
    let judged = |sgm| {
        let v = verdicts(&[run_with_census(sgm)]);
        v.into_iter().find(|v| v.target.contains("fast preset")).unwrap()
    };
    assert!(judged(30_000_000).met && !judged(60_000_000).met);
    assert!(judged(60_000_000)
        .measured
        .contains("110.1M instructions per frame, measured"));
    let json = serde_json::to_value(to_json(runs).unwrap()).unwrap();
    assert_eq!(json["presets"]["frames"][0]["preset"], "fast");
    assert_eq!(json["presets"]["frames"][0]["source"], "measured_frame");
}

#[test]
fn the_learned_preset_is_its_measured_frame_where_the_firmware_ran_one() {
    use presets::{Preset, Source};
    let mut v: Value = serde_json::from_str(&frame_run_json()).unwrap();
    let stages = v["stages"].as_array_mut().unwrap();
    for (name, n, stack) in [
        ("frame_rows", 400_000, 6_000),
        ("frame_encode_pair", 2_000_000_000, 24_000),
        ("frame_head", 300_000_000, 17_000),
        ("frame_sgm", 40_000_000, 7_000),
        ("frame_refine", 60_000_000, 15_000),
    ] {
        stages.push(json!({"name": name, "instructions": n, "arena_in_use": 1, "stack_peak": stack}));
    }
    v["frame"] = json!({"frame": {"height": 120, "width": 160}, "arena_bytes": 467_238, "arena_used": 467_000,
                        "frame_instructions": 2_400_400_000u64, "stack_peak": 24_000});
    let run = CoreRun::parse(&v.to_string()).unwrap();
    // The frame's stages are neither pathway's band pair.
    let plain = frame_run();
    assert_eq!(run.band_pair_instructions(), plain.band_pair_instructions());
    assert_eq!(
        run.native_band_pair_instructions(),
        plain.native_band_pair_instructions()
    );
    assert!(!frame::Pathway::Export.has("frame_head") && !frame::Pathway::Native.has("frame_head"));
    let opts = FrameOptions::default();
    let runs = std::slice::from_ref(&run);
    let frames = FramesReport::new(runs, &[], &opts).unwrap();
    let presets = PresetsReport::new(runs, &frames, &opts.frames).unwrap();
    let learned = |w| {
        presets
            .frames
            .iter()
            .find(|p| p.preset == Preset::Learned && p.frame.width == w)
            .unwrap()
    };
    // Counted at the measured size: its stages, its stack, the preset's arena.
    let at = learned(160);
    assert_eq!((at.instructions, at.source), (2_400_400_000, Source::MeasuredFrame));
    assert_eq!(at.stack_peak_bytes, 24_000);
    assert_eq!(at.arena_bytes, bino_core::preset::arena_bytes(120, 160) as u64);
    assert_eq!(at.frames_per_s_ipc1, 0.166639);
    assert!(presets.measured(&run.core, at.frame, Preset::Learned).is_some());
    // Elsewhere the band pair scaled, as before.
    assert_eq!(learned(320).source, Source::ScaledBandPair);
    let md = presets_markdown(&presets);
    assert!(
        md.contains("| 160x120 | M55 at 400 MHz | learned | `fuse-census+lr+ref` | 2,400,400,000 | measured frame |"),
        "{md}"
    );
}

/// `run_with_census` as the Cortex-M55 measures it with `scripts/firmware.sh --frame320`: both
/// presets on the E7's 320x240 frame too (their own stages and sections).
fn run_with_e7_frame() -> CoreRun {
    let mut v: Value = serde_json::from_str(&frame_run_json()).unwrap();
    let stages = v["stages"].as_array_mut().unwrap();
    for (name, n, arena, stack) in [
        ("census_rows", 100_000u64, 1u64, 900u64),
        ("census_sgm", 30_000_000, 1, 6_000),
        ("census_refine", 50_000_000, 1, 11_000),
        ("frame_encode_pair", 1_000_000_000, 1, 24_000),
        ("census320_rows", 400_000, 38_400, 1_000),
        ("census320_sgm", 250_000_000, 120_000, 6_500),
        ("census320_refine", 150_000_000, 165_936, 12_000),
        ("frame320_rows", 1_000_000, 76_800, 6_000),
        ("frame320_encode_pair", 4_000_000_000, 965_808, 25_000),
        ("frame320_head", 1_000_000_000, 965_808, 18_000),
    ] {
        stages.push(json!({"name": name, "instructions": n, "arena_in_use": arena, "stack_peak": stack}));
    }
    v["census"] = json!({"frame": {"height": 120, "width": 160}, "arena_bytes": 70177, "arena_used": 70176,
                         "frame_instructions": 80_100_000u64, "stack_peak": 11_000});
    v["frame"] = json!({"frame": {"height": 120, "width": 160}, "arena_bytes": 467_238, "arena_used": 467_232,
                        "frame_instructions": 1_000_000_000u64, "stack_peak": 24_000});
    v["census320"] = json!({"frame": {"height": 240, "width": 320}, "arena_bytes": 165_937, "arena_used": 165_936,
                            "frame_instructions": 400_400_000u64, "stack_peak": 12_000});
    v["frame320"] = json!({"frame": {"height": 240, "width": 320}, "arena_bytes": 965_812, "arena_used": 965_808,
                           "frame_instructions": 5_001_000_000u64, "stack_peak": 25_000});
    CoreRun::parse(&v.to_string()).unwrap()
}

#[test]
fn the_e7_frame_is_counted_on_the_core_that_ran_it_and_scaled_on_the_other() {
    use presets::{Preset, Source};
    let m55 = run_with_e7_frame();
    let mut m7_json: Value = serde_json::from_str(&frame_run_json()).unwrap();
    m7_json["core"] = json!("m7");
    let stages = m7_json["stages"].as_array_mut().unwrap();
    stages.push(json!({"name": "census_sgm", "instructions": 60_000_000u64, "arena_in_use": 1, "stack_peak": 5_000}));
    m7_json["census"] = json!({"frame": {"height": 120, "width": 160}, "arena_bytes": 70177, "arena_used": 70176,
                               "frame_instructions": 60_000_000u64, "stack_peak": 5_000});
    let m7 = CoreRun::parse(&m7_json.to_string()).unwrap();

    // The E7 frame's stages are neither pathway's band pair, nor in the static arena.
    let plain = frame_run();
    assert_eq!(m55.band_pair_instructions(), plain.band_pair_instructions());
    assert_eq!(
        m55.native_band_pair_instructions(),
        plain.native_band_pair_instructions()
    );
    for name in ["census320_sgm", "frame320_head", "frame320_encode_pair"] {
        assert!(frame_run_stage(name) && e7_frame_stage(name), "{name}");
        assert!(
            !frame::Pathway::Export.has(name) && !frame::Pathway::Native.has(name),
            "{name}"
        );
    }
    assert!(!e7_frame_stage("census_sgm") && !e7_frame_stage("frame_head"));
    assert_eq!(m55.arena_high_water(), plain.arena_high_water());
    assert_eq!(m55.stack_peak(), 25_000, "the stack is the DTCM's, whichever run");

    let runs = [m55, m7];
    let opts = FrameOptions::default();
    let frames = FramesReport::new(&runs, &[], &opts).unwrap();
    let presets = PresetsReport::new(&runs, &frames, &opts.frames).unwrap();
    let find = |core: &str, preset, w| {
        presets
            .frames
            .iter()
            .find(|p| p.core == core && p.preset == preset && p.frame.width == w)
            .unwrap()
    };
    // The M55 counted both presets on the E7's frame: their stages, stacks and the arenas of
    // the options of that width.
    let fast = find("m55", Preset::Fast, 320);
    assert_eq!((fast.instructions, fast.source), (400_400_000, Source::MeasuredFrame));
    assert_eq!((fast.arena_bytes, fast.stack_peak_bytes), (165_937, 12_000));
    assert_eq!(fast.frames_per_s_ipc1, 0.999001);
    let learned = find("m55", Preset::Learned, 320);
    assert_eq!(
        (learned.instructions, learned.source),
        (5_001_000_000, Source::MeasuredFrame)
    );
    assert_eq!((learned.arena_bytes, learned.stack_peak_bytes), (965_812, 25_000));
    assert_eq!(
        learned.arena_bytes,
        bino_core::preset::arena_bytes_for_width(240, 320) as u64
    );
    assert!(presets.measured("m55", learned.frame, Preset::Learned).is_some());
    // Its 160x120 frames are still their own.
    let small = find("m55", Preset::Fast, 160);
    assert_eq!((small.instructions, small.source), (80_100_000, Source::MeasuredFrame));
    let small = find("m55", Preset::Learned, 160);
    assert_eq!(
        (small.instructions, small.source),
        (1_000_000_000, Source::MeasuredFrame)
    );
    // The M7 measured no E7 frame: its 160x120 frame scaled, its band pair scaled.
    let fast7 = find("m7", Preset::Fast, 320);
    assert_eq!((fast7.instructions, fast7.source), (240_000_000, Source::ScaledFrame));
    assert_eq!(fast7.arena_bytes, 165_937);
    assert_eq!(find("m7", Preset::Learned, 320).source, Source::ScaledBandPair);

    let md = presets_markdown(&presets);
    for row in [
        "| 320x240 | M55 at 400 MHz | fast | `census+lr+ref` | 400,400,000 | measured frame | 0.999 |",
        "| 320x240 | M55 at 400 MHz | learned | `fuse-census+lr+ref` | 5,001,000,000 | measured frame |",
        "| 320x240 | M7 at 480 MHz | fast | `census+lr+ref` | 240,000,000 | scaled from the measured frame |",
        "Counted on a whole frame the firmware ran (\"measured frame\"): M55 160x120, M7 160x120 (fast), M55 \
         320x240.",
        "Scaled, as no frame of that size was measured on that core: M7 160x120 (learned), M7 320x240 (the fast",
    ] {
        assert!(md.contains(row), "{row}\n{md}");
    }
    // The stage table lists the E7 frame's stages for the M55 and none for the M7.
    let table = markdown(&runs);
    assert!(
        table.contains("| frame320_encode_pair | 965,808 B | 25,000 B | 4,000,000,000 |"),
        "{table}"
    );
    assert!(table.contains("frame320_encode_pair | 965,808 B | 25,000 B | 4,000,000,000 | 10000.0 | - | - | - |"));
    assert!(
        table.contains("an arena of their own outside the static one"),
        "{table}"
    );
    assert!(!markdown(&[frame_run()]).contains("census320_"));
    let json = serde_json::to_value(BudgetReport::new(&runs, frames, presets)).unwrap();
    let e7: Vec<&Value> = (json["presets"]["frames"].as_array().unwrap().iter())
        .filter(|p| p["frame"]["width"] == 320)
        .collect();
    let sources: Vec<(&str, &str)> = e7
        .iter()
        .map(|p| (p["core"].as_str().unwrap(), p["source"].as_str().unwrap()))
        .collect();
    assert_eq!(
        sources,
        [
            ("m55", "measured_frame"),
            ("m55", "measured_frame"),
            ("m7", "scaled_frame"),
            ("m7", "scaled_band_pair")
        ]
    );
}
