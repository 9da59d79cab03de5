//! The bar chart (`bino budget --png`), drawn with `plotters` on its bitmap backend: memory per
//! stage (arena in use, stack peak; the arena target as a dashed line) and executed
//! instructions per stage per core (log scale: the encoder passes are 10^4 times the smallest
//! stages). Text uses DejaVu Sans compiled into the binary (`ab_glyph`), so the chart draws the
//! same on a machine without fontconfig or any font installed.

use std::sync::OnceLock;

use anyhow::{anyhow, Result};
use std::ops::Range;

use plotters::coord::ranged1d::{AsRangedCoord, DefaultFormatting, KeyPointHint, ValueFormatter};
use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::{grouped, CoreRun, TARGETS};

/// Chart size in pixels.
pub const SIZE: (u32, u32) = (960, 600);
/// The one font family the chart uses, registered under this name.
const FONT: &str = "sans-serif";
/// Bar colours, one per series (blue, orange).
const COLOURS: [RGBColor; 2] = [RGBColor(33, 150, 228), RGBColor(245, 124, 32)];
const LIMIT_RED: RGBColor = RGBColor(200, 40, 40);

/// One series of bars: a value per stage.
struct Series {
    name: String,
    values: Vec<f64>,
}

/// Registers the embedded font once; an error if the font data does not parse.
fn font() -> Result<()> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED
        .get_or_init(|| plotters::style::register_font(FONT, FontStyle::Normal, dejavu::sans::regular()).is_ok());
    ok.then_some(())
        .ok_or_else(|| anyhow!("the embedded chart font (DejaVu Sans) does not parse"))
}

/// Draws the chart into an RGB image of [`SIZE`].
pub fn draw(runs: &[CoreRun]) -> Result<image::RgbImage> {
    font()?;
    let (w, h) = SIZE;
    let mut pixels = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, SIZE).into_drawing_area();
        root.fill(&WHITE).map_err(plot_error)?;
        let (top, bottom) = root.split_vertically(h / 2);
        let first = &runs[0];
        let stages: Vec<String> = first.stages.iter().map(|s| s.name.clone()).collect();

        let memory = [
            Series {
                name: "arena in use".to_string(),
                values: first.stages.iter().map(|s| s.arena_in_use as f64 / 1024.0).collect(),
            },
            Series {
                name: format!("stack peak ({})", first.core.to_uppercase()),
                values: first.stages.iter().map(|s| s.stack_peak as f64 / 1024.0).collect(),
            },
        ];
        let title = format!(
            "BINO firmware, {}x{} band pair: memory per stage (KiB; weights {} B in flash)",
            first.band.0,
            first.band.1,
            grouped(first.sections.weights)
        );
        // In KiB, so the axis' round numbers are round in KiB.
        let arena_target = TARGETS.arena_bytes as f64 / 1024.0;
        let top_value = max_of(&memory).max(arena_target) * 1.2;
        let limit = Limit {
            value: arena_target,
            label: format!("arena target {arena_target:.0}K"),
        };
        panel(&top, &title, &stages, &memory, (0.0, 0.0..top_value), Some(limit), &kib)?;

        let instructions: Vec<Series> = runs
            .iter()
            .map(|r| Series {
                name: format!("{} instructions", r.core.to_uppercase()),
                values: stages
                    .iter()
                    .map(|name| r.stage_instructions(name).map_or(0.0, |n| n as f64))
                    .collect(),
            })
            .collect();
        // Room above the tallest bar for its label and the legend: two decades.
        let top_value = max_of(&instructions).max(10.0) * 100.0;
        let title = "executed instructions per stage (log scale; QEMU counts, not cycles)";
        let y = (1.0..top_value).log_scale();
        panel(&bottom, title, &stages, &instructions, (1.0, y), None, &si)?;
        root.present().map_err(plot_error)?;
    }
    image::RgbImage::from_raw(w, h, pixels).ok_or_else(|| anyhow!("chart buffer of the wrong size"))
}

/// A horizontal target line across a panel.
struct Limit {
    value: f64,
    label: String,
}

fn max_of(series: &[Series]) -> f64 {
    series.iter().flat_map(|s| s.values.iter().copied()).fold(1.0, f64::max)
}

/// The x axis: stage `i` spans `[i, i + 1)`, its name under the centre.
struct StageAxis {
    stages: usize,
}

impl Ranged for StageAxis {
    type FormatOption = DefaultFormatting;
    type ValueType = f64;

    fn map(&self, value: &f64, limit: (i32, i32)) -> i32 {
        let f = value / self.stages.max(1) as f64;
        limit.0 + (f * (limit.1 - limit.0) as f64).round() as i32
    }

    fn key_points<Hint: KeyPointHint>(&self, _hint: Hint) -> Vec<f64> {
        (0..self.stages).map(|i| i as f64 + 0.5).collect()
    }

    fn range(&self) -> Range<f64> {
        0.0..self.stages as f64
    }
}

/// One panel of grouped bars, a group per stage, a bar per series, each labelled with its
/// value; `(base, y)`: the value axis (linear or log) and the value the bars rise from.
fn panel<Y>(
    area: &DrawingArea<BitMapBackend<'_>, Shift>,
    title: &str,
    stages: &[String],
    series: &[Series],
    (base, y): (f64, Y),
    limit: Option<Limit>,
    label: &dyn Fn(f64) -> String,
) -> Result<()>
where
    Y: AsRangedCoord<Value = f64>,
    Y::CoordDescType: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let n = stages.len().max(1);
    let x = StageAxis { stages: n };
    let mut chart = ChartBuilder::on(area)
        .margin(10)
        .caption(title, (FONT, 15))
        .x_label_area_size(24)
        .y_label_area_size(60)
        .build_cartesian_2d(x, y)
        .map_err(plot_error)?;
    let stage_of = |x: &f64| stages.get(x.floor() as usize).cloned().unwrap_or_default();
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(n)
        .x_label_formatter(&stage_of)
        .y_label_formatter(&|v| tidy(label(*v)))
        .label_style((FONT, 12))
        .light_line_style(WHITE)
        .draw()
        .map_err(plot_error)?;

    let group = 0.8;
    let bar_w = group / series.len().max(1) as f64;
    for (k, s) in series.iter().enumerate() {
        let colour = COLOURS[k % COLOURS.len()];
        let x0 = |i: usize| i as f64 + (1.0 - group) / 2.0 + k as f64 * bar_w;
        let bars = s
            .values
            .iter()
            .enumerate()
            .map(|(i, &v)| Rectangle::new([(x0(i), base), (x0(i) + bar_w * 0.9, v.max(base))], colour.filled()));
        chart
            .draw_series(bars)
            .map_err(plot_error)?
            .label(s.name.as_str())
            .legend(move |(lx, ly)| Rectangle::new([(lx, ly - 5), (lx + 12, ly + 5)], colour.filled()));
        // Neighbouring labels alternate in height so wide ones do not overlap.
        let text = (FONT, 11)
            .into_font()
            .color(&BLACK)
            .pos(Pos::new(HPos::Center, VPos::Bottom));
        let labels = s.values.iter().enumerate().map(|(i, &v)| {
            EmptyElement::at((x0(i) + bar_w * 0.45, v.max(base)))
                + Text::new(label(v), (0, -3 - 12 * (k as i32 % 2)), text.clone())
        });
        chart.draw_series(labels).map_err(plot_error)?;
    }
    if let Some(limit) = limit {
        let style = LIMIT_RED.stroke_width(1);
        let line = [(0.0, limit.value), (n as f64, limit.value)];
        chart
            .draw_series(DashedLineSeries::new(line, 6, 4, style))
            .map_err(plot_error)?
            .label(limit.label.as_str())
            .legend(move |(lx, ly)| PathElement::new([(lx, ly), (lx + 12, ly)], style));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .label_font((FONT, 12))
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK)
        .draw()
        .map_err(plot_error)?;
    Ok(())
}

fn plot_error<E: std::error::Error + Send + Sync>(e: DrawingAreaErrorKind<E>) -> anyhow::Error {
    anyhow!("drawing the budget chart: {e}")
}

/// A value in KiB as `476K`.
fn kib(v: f64) -> String {
    format!("{v:.0}K")
}

/// An axis label without trailing zeros: `1.00G` as `1G`, `2.50M` as `2.5M`.
fn tidy(label: String) -> String {
    match label.split_once('.') {
        Some((whole, rest)) => {
            let digits = rest.trim_end_matches(|c: char| !c.is_ascii_digit());
            let unit = &rest[digits.len()..];
            let digits = digits.trim_end_matches('0');
            match digits {
                "" => format!("{whole}{unit}"),
                d => format!("{whole}.{d}{unit}"),
            }
        }
        None => label,
    }
}

/// `1.73G`, `8.5M`, `22k`: instruction counts short enough to sit on a bar.
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn labels_are_short() {
        assert_eq!(si(11_670_000_000.0), "11.67G");
        assert_eq!(si(8_549_536.0), "8.5M");
        assert_eq!(si(21_520.0), "22k");
        assert_eq!(tidy(si(1e9)), "1G");
        assert_eq!(tidy(si(2.5e6)), "2.5M");
        assert_eq!(tidy(si(100.0)), "100");
        assert_eq!(tidy(kib(200.0)), "200K");
    }
}
