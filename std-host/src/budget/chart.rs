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

use super::{e7_frame_stage, grouped, CoreRun, StageRun, CENSUS_PREFIX, FRAME_PREFIX, NATIVE_PREFIX, TARGETS};

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

/// The stages the chart draws: all but the learned frame's (the native band pair's again, four
/// bands' worth) and the E7 frame's (both presets again on a larger frame); the presets table
/// has them.
pub(super) fn charted_stages(run: &CoreRun) -> Vec<&StageRun> {
    (run.stages.iter())
        .filter(|s| !s.name.starts_with(FRAME_PREFIX) && !e7_frame_stage(&s.name))
        .collect()
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
        let charted = charted_stages(first);
        let stages: Vec<String> = charted.iter().map(|s| s.name.clone()).collect();

        let memory = [
            Series {
                name: "arena in use".to_string(),
                values: charted.iter().map(|s| s.arena_in_use as f64 / 1024.0).collect(),
            },
            Series {
                name: format!("stack peak ({})", first.core.to_uppercase()),
                values: charted.iter().map(|s| s.stack_peak as f64 / 1024.0).collect(),
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

/// Height of a panel's header: its title and under it the legend, outside the plot, so no bar
/// or value label can meet the legend.
const HEADER: u32 = 44;
/// Height of the x label area: two lines of stage name, then the pathway captions.
const X_LABEL_AREA: u32 = 50;
/// Font size of the axis labels, legend and captions.
const LABEL_SIZE: u32 = 12;
/// Vertical distance of the x label rows, pixels.
const ROW_STEP: i32 = 14;
/// Least horizontal gap between two labels on one row, pixels.
#[cfg(test)]
pub(super) const LABEL_GAP: i32 = 4;

/// A stage's label: its name without the `native_` or `census_` prefix (the caption under it
/// says so), split into two lines at its first `_`.
pub(super) fn stage_label(name: &str) -> Vec<String> {
    let short = name
        .strip_prefix(NATIVE_PREFIX)
        .or_else(|| name.strip_prefix(CENSUS_PREFIX))
        .unwrap_or(name);
    match short.split_once('_') {
        Some((a, b)) => vec![a.to_string(), b.to_string()],
        None => vec![short.to_string()],
    }
}

/// The pathway captions under the stage names: (caption, first stage, one past the last), for
/// each run of consecutive stages of one group (boot, export, native, the fast preset's frame).
pub(super) fn groups(stages: &[String]) -> Vec<(&'static str, usize, usize)> {
    let group = |name: &str| {
        if name == "load" {
            "boot"
        } else if name.starts_with(NATIVE_PREFIX) {
            "native pathway"
        } else if name.starts_with(CENSUS_PREFIX) {
            "census frame"
        } else {
            "export pathway"
        }
    };
    let mut out: Vec<(&'static str, usize, usize)> = Vec::new();
    for (i, name) in stages.iter().enumerate() {
        let g = group(name);
        match out.last_mut() {
            Some(last) if last.0 == g => last.2 = i + 1,
            _ => out.push((g, i, i + 1)),
        }
    }
    out
}

/// A text placed under the plot: its row (0 and 1: stage names, 2: captions) and horizontal
/// extent in pixels.
#[derive(Debug, Clone, PartialEq, Eq)]
pub(super) struct Placed {
    pub text: String,
    pub row: i32,
    pub left: i32,
    pub width: i32,
}

/// Where the x labels go for a plot spanning pixels `x0..x1`, each text centred under its stage
/// (or its group's stages), `measure` giving a text's width in pixels.
pub(super) fn x_label_layout(stages: &[String], (x0, x1): (i32, i32), measure: &dyn Fn(&str) -> i32) -> Vec<Placed> {
    let slot = f64::from(x1 - x0) / stages.len().max(1) as f64;
    let centre = |from: usize, to: usize| x0 + ((from + to) as f64 * slot / 2.0).round() as i32;
    let place = |text: &str, row: i32, mid: i32| {
        let width = measure(text);
        Placed {
            text: text.to_string(),
            row,
            left: mid - width / 2,
            width,
        }
    };
    let mut out = Vec::new();
    for (i, name) in stages.iter().enumerate() {
        for (row, line) in stage_label(name).iter().enumerate() {
            out.push(place(line, row as i32, centre(i, i + 1)));
        }
    }
    for (caption, from, to) in groups(stages) {
        out.push(place(caption, 2, centre(from, to)));
    }
    out
}

/// Width of `text` in the chart's label font, pixels (12 a character if the font is missing,
/// more than any of its glyphs).
pub(super) fn text_width(text: &str) -> i32 {
    let _ = font();
    (FONT, LABEL_SIZE)
        .into_font()
        .box_size(text)
        .map_or(text.len() as i32 * LABEL_SIZE as i32, |(w, _)| w as i32)
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
    let (header, body) = area.split_vertically(HEADER);
    header
        .draw(&Text::new(
            title.to_string(),
            (header.dim_in_pixel().0 as i32 / 2, 6),
            (FONT, 15)
                .into_font()
                .color(&BLACK)
                .pos(Pos::new(HPos::Center, VPos::Top)),
        ))
        .map_err(plot_error)?;
    legend(&header, series, limit.as_ref())?;

    let x = StageAxis { stages: n };
    let mut chart = ChartBuilder::on(&body)
        .margin(10)
        .margin_top(4)
        .x_label_area_size(X_LABEL_AREA)
        .y_label_area_size(60)
        .build_cartesian_2d(x, y)
        .map_err(plot_error)?;
    chart
        .configure_mesh()
        .disable_x_mesh()
        .x_labels(n)
        // The stage names are drawn below, on two lines where they are long.
        .x_label_formatter(&|_| String::new())
        .y_label_formatter(&|v| tidy(label(*v)))
        .label_style((FONT, LABEL_SIZE))
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
        chart.draw_series(bars).map_err(plot_error)?;
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
    if let Some(limit) = &limit {
        let style = LIMIT_RED.stroke_width(1);
        let line = [(0.0, limit.value), (n as f64, limit.value)];
        chart
            .draw_series(DashedLineSeries::new(line, 6, 4, style))
            .map_err(plot_error)?;
    }

    // The plot's pixels, relative to the panel's area.
    let plot = chart.plotting_area();
    let (origin, (pw, ph)) = (area.get_base_pixel(), plot.dim_in_pixel());
    let at = plot.get_base_pixel();
    let (x0, top) = (at.0 - origin.0, at.1 - origin.1);
    let (x1, bottom) = (x0 + pw as i32, top + ph as i32);
    // A grey rule between the pathways' groups.
    let slot = f64::from(x1 - x0) / n as f64;
    for (_, from, _) in groups(stages).iter().skip(1) {
        let gx = x0 + (*from as f64 * slot).round() as i32;
        area.draw(&PathElement::new(
            [(gx, top), (gx, bottom + 2 * ROW_STEP + 4)],
            RGBColor(160, 160, 160),
        ))
        .map_err(plot_error)?;
    }
    let style = (FONT, LABEL_SIZE)
        .into_font()
        .color(&BLACK)
        .pos(Pos::new(HPos::Center, VPos::Top));
    for p in x_label_layout(stages, (x0, x1), &text_width) {
        let yy = bottom + 5 + p.row * ROW_STEP + if p.row == 2 { 4 } else { 0 };
        area.draw(&Text::new(p.text, (p.left + p.width / 2, yy), style.clone()))
            .map_err(plot_error)?;
    }
    Ok(())
}

/// The legend on one line under the panel's title: a swatch and a name per series, then the
/// target line's.
fn legend(header: &DrawingArea<BitMapBackend<'_>, Shift>, series: &[Series], limit: Option<&Limit>) -> Result<()> {
    let mut entries: Vec<(Option<RGBColor>, &str)> = series
        .iter()
        .enumerate()
        .map(|(k, s)| (Some(COLOURS[k % COLOURS.len()]), s.name.as_str()))
        .collect();
    if let Some(l) = limit {
        entries.push((None, l.label.as_str()));
    }
    let swatch = 12;
    let widths: Vec<i32> = entries.iter().map(|(_, name)| swatch + 4 + text_width(name)).collect();
    let spacing = 18;
    let total: i32 = widths.iter().sum::<i32>() + spacing * (entries.len() as i32 - 1).max(0);
    let mut x = (header.dim_in_pixel().0 as i32 - total) / 2;
    let y = 30;
    let text = (FONT, LABEL_SIZE)
        .into_font()
        .color(&BLACK)
        .pos(Pos::new(HPos::Left, VPos::Center));
    for ((colour, name), w) in entries.iter().zip(&widths) {
        match colour {
            Some(c) => header
                .draw(&Rectangle::new([(x, y - 5), (x + swatch, y + 5)], c.filled()))
                .map_err(plot_error)?,
            None => header
                .draw(&PathElement::new([(x, y), (x + swatch, y)], LIMIT_RED.stroke_width(1)))
                .map_err(plot_error)?,
        }
        header
            .draw(&Text::new(name.to_string(), (x + swatch + 4, y), text.clone()))
            .map_err(plot_error)?;
        x += w + spacing;
    }
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
