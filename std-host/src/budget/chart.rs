//! The bar chart: memory per stage (arena in use, stack peak) and instructions per stage per
//! core (log scale: the encoder passes are 10^4 times the smallest stages).

use embedded_graphics::mono_font::ascii::FONT_6X10;
use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::pixelcolor::Rgb565;
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::{PrimitiveStyle, Rectangle};
use embedded_graphics::text::{Alignment, Text};

use super::{grouped, CoreRun};
use crate::sim::display::{DisplaySize, Framebuffer};

const W: usize = 960;
const H: usize = 600;
const BAR_COLOURS: [Rgb565; 3] = [
    Rgb565::new(4, 40, 28),  // blue-ish
    Rgb565::new(30, 30, 4),  // orange
    Rgb565::new(10, 50, 10), // green
];

fn text(fb: &mut Framebuffer, s: &str, x: i32, y: i32, align: Alignment) {
    let style = MonoTextStyle::new(&FONT_6X10, Rgb565::BLACK);
    let _ = Text::with_alignment(s, Point::new(x, y), style, align).draw(fb);
}

fn bar(fb: &mut Framebuffer, x: i32, y_base: i32, w: u32, h: u32, c: Rgb565) {
    let _ = Rectangle::new(Point::new(x, y_base - h as i32), Size::new(w, h.max(1)))
        .into_styled(PrimitiveStyle::with_fill(c))
        .draw(fb);
}

/// One panel of grouped bars; `series` are (label, values per stage).
#[allow(clippy::too_many_arguments)]
fn panel(
    fb: &mut Framebuffer,
    top: i32,
    height: i32,
    title: &str,
    stages: &[String],
    series: &[(String, Vec<f64>)],
    log: bool,
    limit: Option<(f64, &str)>,
    label: &dyn Fn(f64) -> String,
) {
    let (left, right) = (50, W as i32 - 20);
    let base = top + height - 30;
    let plot_h = (height - 80) as f64;
    text(fb, title, left, top + 12, Alignment::Left);
    let max = series
        .iter()
        .flat_map(|(_, v)| v.iter().copied())
        .chain(limit.map(|(v, _)| v))
        .fold(1.0f64, f64::max);
    let scale = |v: f64| -> u32 {
        let f = if log {
            if v < 1.0 {
                0.0
            } else {
                v.log10() / max.log10().max(1.0)
            }
        } else {
            v / max
        };
        (f.clamp(0.0, 1.0) * plot_h) as u32
    };
    let _ = Rectangle::new(Point::new(left, base), Size::new((right - left) as u32, 1))
        .into_styled(PrimitiveStyle::with_fill(Rgb565::BLACK))
        .draw(fb);
    if let Some((v, name)) = limit {
        let y = base - scale(v) as i32;
        let red = Rgb565::new(28, 8, 4);
        for x in (left..right).step_by(8) {
            let _ = Rectangle::new(Point::new(x, y), Size::new(5, 1))
                .into_styled(PrimitiveStyle::with_fill(red))
                .draw(fb);
        }
        text(fb, name, left - 4, y + 3, Alignment::Right);
    }
    let group_w = (right - left) / stages.len().max(1) as i32;
    let bar_w = ((group_w - 16) / series.len().max(1) as i32).max(2);
    for (i, stage) in stages.iter().enumerate() {
        let gx = left + i as i32 * group_w + 8;
        for (k, (_, values)) in series.iter().enumerate() {
            let v = values.get(i).copied().unwrap_or(0.0);
            let h = scale(v);
            let x = gx + k as i32 * bar_w;
            bar(fb, x, base, bar_w as u32 - 2, h, BAR_COLOURS[k % BAR_COLOURS.len()]);
            text(
                fb,
                &label(v),
                x + bar_w / 2,
                base - h as i32 - 3 - 10 * (k as i32 % 2),
                Alignment::Center,
            );
        }
        text(fb, stage, gx + group_w / 2 - 8, base + 14, Alignment::Center);
    }
    for (k, (name, _)) in series.iter().enumerate() {
        let x = right - 160 * (series.len() - k) as i32;
        bar(fb, x, top + 14, 10, 10, BAR_COLOURS[k % BAR_COLOURS.len()]);
        text(fb, name, x + 14, top + 12, Alignment::Left);
    }
}

fn si(v: f64) -> String {
    if v >= 1e9 {
        format!("{:.2}G", v / 1e9)
    } else if v >= 1e6 {
        format!("{:.1}M", v / 1e6)
    } else if v >= 1e3 {
        format!("{:.0}k", v / 1e3)
    } else {
        format!("{v:.0}")
    }
}

pub fn draw(runs: &[CoreRun]) -> Framebuffer {
    let mut fb = Framebuffer::new(DisplaySize { width: W, height: H });
    let _ = fb.clear(Rgb565::WHITE);
    let first = &runs[0];
    let stages: Vec<String> = first.stages.iter().map(|s| s.name.clone()).collect();
    let kib = |v: f64| format!("{:.0}K", v / 1024.0);
    let memory = vec![
        (
            "arena in use".to_string(),
            first.stages.iter().map(|s| s.arena_in_use as f64).collect(),
        ),
        (
            format!("stack peak ({})", first.core.to_uppercase()),
            first.stages.iter().map(|s| s.stack_peak as f64).collect(),
        ),
    ];
    let title = format!(
        "BINO firmware, {}x{} band pair: memory per stage (bytes; weights {} B in flash)",
        first.band.0,
        first.band.1,
        grouped(first.sections.weights)
    );
    let arena_limit = Some((super::TARGETS.arena_bytes as f64, "512K"));
    panel(&mut fb, 10, 280, &title, &stages, &memory, false, arena_limit, &kib);
    let instructions: Vec<(String, Vec<f64>)> = runs
        .iter()
        .map(|r| {
            let values = stages
                .iter()
                .map(|name| {
                    r.stages
                        .iter()
                        .find(|s| &s.name == name)
                        .map_or(0.0, |s| s.instructions as f64)
                })
                .collect();
            (format!("{} instructions", r.core.to_uppercase()), values)
        })
        .collect();
    panel(
        &mut fb,
        300,
        290,
        "executed instructions per stage (log scale; QEMU counts, not cycles)",
        &stages,
        &instructions,
        true,
        None,
        &si,
    );
    fb
}
