//! `bino-example-host LEFT RIGHT OUT.png`: the refined disparity of a rectified pair, as an
//! 8-bit grey PNG at 160 px wide (8 grey levels per pixel of disparity).

use std::path::Path;
use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [left, right, out] = args.as_slice() else {
        eprintln!("usage: bino-example-host LEFT RIGHT OUT.png  (a rectified pair: PNG, JPEG or PGM/PPM)");
        return ExitCode::from(2);
    };
    match run(Path::new(left), Path::new(right), Path::new(out)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn run(left: &Path, right: &Path, out: &Path) -> Result<(), Box<dyn std::error::Error>> {
    let open = |p: &Path| image::open(p).map_err(|e| format!("{}: {e}", p.display()));
    let start = std::time::Instant::now();
    let d = bino_example_host::disparity(&open(left)?, &open(right)?)?;
    bino_example_host::save(&d, out)?;
    let max = d.q8.iter().max().map_or(0.0, |&m| f32::from(m) / 256.0);
    println!(
        "{}: {}x{} disparity (grey = 8 x px, max {max:.1} px at this width) in {:.2} s",
        out.display(),
        d.width,
        d.height,
        start.elapsed().as_secs_f32()
    );
    Ok(())
}
