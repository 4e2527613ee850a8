//! `--plot`: the paper's Fig. 1 (right) for the final iteration: the residual histogram (raw
//! counts as bars, the smoothed histogram the model is fitted to), the fitted inlier model G
//! with σ (and σ+β dashed while β is not negligible), and P(inlier | r) on a secondary 0..1 axis.
//!
//! Text is drawn from a font compiled into the binary (no system font libraries); PNG pixels
//! are encoded with the `png` crate, SVG is written by plotters.
//!
//! The one drawing of Fig. 1: the paper reproduction (examples/experiments/plots.rs) compiles
//! this file, with `glyphs` and `numbers`, into itself rather than drawing its own.
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;
use std::sync::Once;

use ab_glyph::FontRef;
use plotters::chart::DualCoordChartContext;
use plotters::coord::Shift;
use plotters::coord::types::RangedCoordf64;
use plotters::element::DashedPathElement;
use plotters::prelude::*;
use plotters::series::DashedLineSeries;
use plotters::style::FontStyle;
use sie::{HistogramModel, ModelWidth};

use super::glyphs::GlyphText;

/// Pixel size of one histogram panel; several histograms (per-column mode) stack vertically.
const WIDTH: u32 = 1000;
const PANEL_HEIGHT: u32 = 560;
const TITLE_HEIGHT: u32 = 50;
/// Model curves are sampled this finely across the histogram range.
const CURVE_SAMPLES: usize = 400;
/// The σ+β curve is drawn only while β is at least this fraction of σ.
const VISIBLE_BETA_RATIO: f64 = 0.01;

const BAR_COLOUR: RGBColor = RGBColor(158, 190, 222);
const SMOOTHED_COLOUR: RGBColor = RGBColor(31, 86, 150);
const MODEL_COLOUR: RGBColor = RGBColor(204, 40, 40);
const PROBABILITY_COLOUR: RGBColor = RGBColor(30, 140, 60);

/// Output format, from the file extension.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum PlotFormat {
    Png,
    Svg,
}

impl PlotFormat {
    pub fn of(path: &Path) -> Result<PlotFormat, String> {
        let extension = path
            .extension()
            .and_then(|e| e.to_str())
            .unwrap_or("")
            .to_ascii_lowercase();
        match extension.as_str() {
            "png" => Ok(PlotFormat::Png),
            "svg" => Ok(PlotFormat::Svg),
            _ => Err(format!(
                "{}: --plot writes .png or .svg, not {extension:?}",
                path.display()
            )),
        }
    }
}

/// Text around the panels.
pub struct PlotText<'a> {
    pub title: &'a str,
    /// The x axis, e.g. "|r| (input units)".
    pub x_label: &'a str,
    /// One caption per histogram (empty for a single one).
    pub panel_captions: Vec<String>,
}

/// Draws the histograms to `path` (.png or .svg). Errors are one line naming the file.
pub fn write_plot(path: &Path, models: &[HistogramModel], text: &PlotText) -> Result<(), String> {
    let fail = |e: &dyn std::fmt::Display| format!("{}: cannot draw the plot: {e}", path.display());
    if models.is_empty()
        || models
            .iter()
            .any(|m| m.bins() == 0 || m.hi.partial_cmp(&m.lo) != Some(std::cmp::Ordering::Greater))
    {
        return Err(fail(&"no fitted histogram to draw"));
    }
    register_font();
    let panels = u32::try_from(models.len()).unwrap_or(u32::MAX).min(16);
    let size = (WIDTH, TITLE_HEIGHT + PANEL_HEIGHT * panels);
    match PlotFormat::of(path)? {
        PlotFormat::Svg => {
            let root = SVGBackend::new(path, size).into_drawing_area();
            draw(root, models, text).map_err(|e| fail(&e))
        }
        PlotFormat::Png => {
            let mut pixels = vec![0u8; size.0 as usize * size.1 as usize * 3];
            {
                let font = FontRef::try_from_slice(ttf_noto_sans::REGULAR).map_err(|e| fail(&e))?;
                let bitmap = BitMapBackend::with_buffer(&mut pixels, size);
                let root = GlyphText::new(bitmap, font).into_drawing_area();
                draw(root, models, text).map_err(|e| fail(&e))?;
            }
            write_png(path, size, &pixels).map_err(|e| fail(&e))
        }
    }
}

/// Makes the embedded font plotters' "sans-serif" family.
fn register_font() {
    static REGISTER: Once = Once::new();
    REGISTER.call_once(|| {
        // The font is a fixed, valid TrueType file; if it were not, text would be missing and
        // drawing would report FontUnavailable.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, ttf_noto_sans::REGULAR);
    });
}

fn write_png(path: &Path, (width, height): (u32, u32), rgb: &[u8]) -> Result<(), String> {
    let file = File::create(path).map_err(|e| e.to_string())?;
    let mut encoder = png::Encoder::new(BufWriter::new(file), width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().map_err(|e| e.to_string())?;
    writer.write_image_data(rgb).map_err(|e| e.to_string())?;
    writer.finish().map_err(|e| e.to_string())
}

type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// A panel's chart: counts on the left axis, P(inlier | r) on the right, both over r.
type PanelChart<'a, DB> = DualCoordChartContext<
    'a,
    DB,
    Cartesian2d<RangedCoordf64, RangedCoordf64>,
    Cartesian2d<RangedCoordf64, RangedCoordf64>,
>;

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    models: &[HistogramModel],
    text: &PlotText,
) -> DrawResult<DB> {
    root.fill(&WHITE)?;
    let (title_area, body) = root.split_vertically(TITLE_HEIGHT);
    title_area.titled(text.title, ("sans-serif", 22))?;
    let panels = body.split_evenly((models.len(), 1));
    for (index, (area, model)) in panels.iter().zip(models).enumerate() {
        let caption = text.panel_captions.get(index).map(String::as_str).unwrap_or("");
        draw_panel(area, model, text.x_label, caption)?;
    }
    root.present()
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    model: &HistogramModel,
    x_label: &str,
    caption: &str,
) -> DrawResult<DB> {
    let (lo, hi) = (model.lo, model.hi);
    let mut builder = ChartBuilder::on(area);
    builder
        .margin(14)
        .x_label_area_size(50)
        .y_label_area_size(75)
        .right_y_label_area_size(70);
    if !caption.is_empty() {
        builder.caption(caption, ("sans-serif", 18));
    }
    let mut chart = builder
        .build_cartesian_2d(lo..hi, 0.0..count_axis_top(model))?
        .set_secondary_coord(lo..hi, 0.0..1.0);
    chart
        .configure_mesh()
        .light_line_style(WHITE.mix(0.0))
        .bold_line_style(BLACK.mix(0.08))
        .x_desc(x_label)
        .y_desc("residuals per bin")
        .y_label_formatter(&|count| format!("{count:.0}"))
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .draw()?;
    chart
        .configure_secondary_axes()
        .y_desc("P(inlier | r)")
        .label_style(("sans-serif", 15))
        .axis_desc_style(("sans-serif", 17))
        .draw()?;
    draw_curves(&mut chart, model)?;
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .label_font(("sans-serif", 15))
        .background_style(WHITE.mix(0.9))
        .border_style(BLACK.mix(0.4))
        .draw()
}

/// Top of the count axis: the highest bar or curve with a tenth more above it.
fn count_axis_top(model: &HistogramModel) -> f64 {
    let peak = model
        .counts
        .iter()
        .chain(&model.smoothed)
        .copied()
        .chain([
            model.model(model.inlier.mu, ModelWidth::Sigma),
            model.model(model.inlier.mu, ModelWidth::SigmaPlusBeta),
        ])
        .filter(|v| v.is_finite())
        .fold(0.0, f64::max);
    if peak > 0.0 { peak * 1.1 } else { 1.0 }
}

/// The histogram bars, the smoothed histogram, the fitted model (with σ + β while β shows) and
/// P(inlier | r), each with its legend entry.
fn draw_curves<DB: DrawingBackend>(chart: &mut PanelChart<DB>, model: &HistogramModel) -> DrawResult<DB> {
    let (lo, hi) = (model.lo, model.hi);
    let width = model.bin_width();
    let grid: Vec<f64> = (0..=CURVE_SAMPLES)
        .map(|i| lo + (hi - lo) * i as f64 / CURVE_SAMPLES as f64)
        .collect();
    chart
        .draw_series(model.counts.iter().enumerate().map(|(bin, &count)| {
            let left = lo + bin as f64 * width;
            Rectangle::new([(left, 0.0), (left + width, count)], BAR_COLOUR.filled())
        }))?
        .label("histogram (counts)")
        .legend(|(x, y)| Rectangle::new([(x, y - 6), (x + 18, y + 6)], BAR_COLOUR.filled()));
    chart
        .draw_series(LineSeries::new(
            (0..model.bins()).map(|bin| (model.bin_centre(bin), model.smoothed[bin])),
            SMOOTHED_COLOUR.stroke_width(2),
        ))?
        .label("smoothed histogram (fitted to)")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 18, y)], SMOOTHED_COLOUR.stroke_width(2)));
    chart
        .draw_series(LineSeries::new(
            grid.iter().map(|&x| (x, model.model(x, ModelWidth::Sigma))),
            MODEL_COLOUR.stroke_width(3),
        ))?
        .label(format!(
            "fitted inlier model G (σ = {})",
            super::numbers::significant(model.inlier.sigma)
        ))
        .legend(|(x, y)| PathElement::new([(x, y), (x + 18, y)], MODEL_COLOUR.stroke_width(3)));
    if model.beta >= VISIBLE_BETA_RATIO * model.inlier.sigma {
        chart
            .draw_series(DashedLineSeries::new(
                grid.iter()
                    .map(|&x| (x, model.model(x, ModelWidth::SigmaPlusBeta))),
                8,
                6,
                MODEL_COLOUR.stroke_width(2),
            ))?
            .label(format!(
                "G with σ + β (β = {})",
                super::numbers::significant(model.beta)
            ))
            .legend(|(x, y)| {
                DashedPathElement::new([(x, y), (x + 18, y)], 5, 3, MODEL_COLOUR.stroke_width(2))
            });
    }
    chart
        .draw_secondary_series(LineSeries::new(
            grid.iter().map(|&x| (x, model.probability(x))),
            PROBABILITY_COLOUR.stroke_width(2),
        ))?
        .label("P(inlier | r), right axis")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 18, y)], PROBABILITY_COLOUR.stroke_width(2)));
    Ok(())
}
