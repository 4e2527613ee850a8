//! SVG figures: the paper's failure-ratio / mean-error panels (2 rows × 3 outlier levels, one
//! line per method) and the residual histogram with the fitted model and P(inlier | r)
//! (Fig. 1, right; drawn by the CLI's `--plot` code). SVG keeps the files small and leaves text
//! rendering to the viewer; the embedded Noto Sans is registered only so plotters can measure
//! text for the layout.
use std::path::Path;
use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::FontStyle;
use sie::HistogramModel;

/// Distinct colours for up to 10 series (methods); the first (SIE) is black as in the paper.
pub const PALETTE: [RGBColor; 10] = [
    RGBColor(0, 0, 0),
    RGBColor(214, 39, 40),
    RGBColor(31, 119, 180),
    RGBColor(227, 119, 194),
    RGBColor(44, 160, 44),
    RGBColor(127, 127, 127),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(23, 190, 207),
];

const PANEL_WIDTH: u32 = 420;
const PANEL_HEIGHT: u32 = 300;
const TITLE_HEIGHT: u32 = 40;
const LEGEND_ROW_HEIGHT: u32 = 26;
const LEGEND_ENTRY_WIDTH: u32 = 250;

/// One line of a panel; NaN values leave a gap.
pub struct Series {
    pub label: String,
    pub colour: RGBColor,
    pub points: Vec<(f64, f64)>,
}

/// One chart of a panel grid.
pub struct Panel {
    pub title: String,
    pub x_label: String,
    pub x_range: (f64, f64),
    pub series: Vec<Series>,
}

/// The y axis shared by every panel of a figure.
#[derive(Clone, Copy)]
pub enum YAxis {
    /// Failure ratio in [0, 1].
    Ratio,
    /// Mean error on a log axis between the two bounds.
    Log(f64, f64),
}

/// Makes the embedded font plotters' "sans-serif" family (text measurement needs a font).
fn register_font() {
    static REGISTER: Once = Once::new();
    REGISTER.call_once(|| {
        // A fixed, valid TrueType file: registration cannot fail in practice, and if it did the
        // drawing below would report the missing font.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, ttf_noto_sans::REGULAR);
    });
}

/// Draws `panels` in a grid of `columns` columns with one legend for all of them.
pub fn panel_grid(
    path: &Path,
    title: &str,
    columns: usize,
    panels: &[Panel],
    y_label: &str,
    y_axis: YAxis,
) -> Result<(), String> {
    register_font();
    let rows = panels.len().div_ceil(columns);
    let legend: Vec<(String, RGBColor)> = panels
        .first()
        .map(|p| p.series.iter().map(|s| (s.label.clone(), s.colour)).collect())
        .unwrap_or_default();
    let width = PANEL_WIDTH * columns as u32;
    let per_row = (width / LEGEND_ENTRY_WIDTH).max(1) as usize;
    let legend_height = LEGEND_ROW_HEIGHT * legend.len().div_ceil(per_row) as u32 + 10;
    let size = (width, TITLE_HEIGHT + legend_height + PANEL_HEIGHT * rows as u32);
    let root = SVGBackend::new(path, size).into_drawing_area();
    let fail = |e: &dyn std::fmt::Display| format!("{}: {e}", path.display());
    root.fill(&WHITE).map_err(|e| fail(&e))?;
    let (head, body) = root.split_vertically(TITLE_HEIGHT);
    head.titled(title, ("sans-serif", 20)).map_err(|e| fail(&e))?;
    let (legend_area, body) = body.split_vertically(legend_height);
    draw_legend(&legend_area, &legend, per_row).map_err(|e| fail(&e))?;
    let areas = body.split_evenly((rows, columns));
    for (area, panel) in areas.iter().zip(panels) {
        draw_panel(area, panel, y_label, y_axis).map_err(|e| fail(&e))?;
    }
    root.present().map_err(|e| fail(&e))
}

type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

fn draw_legend<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    entries: &[(String, RGBColor)],
    per_row: usize,
) -> DrawResult<DB> {
    for (i, (label, colour)) in entries.iter().enumerate() {
        let x = 20 + (i % per_row) as i32 * LEGEND_ENTRY_WIDTH as i32;
        let y = 14 + (i / per_row) as i32 * LEGEND_ROW_HEIGHT as i32;
        area.draw(&PathElement::new(
            vec![(x, y), (x + 28, y)],
            colour.stroke_width(3),
        ))?;
        area.draw(&Text::new(
            label.clone(),
            (x + 36, y - 8),
            ("sans-serif", 15).into_font(),
        ))?;
    }
    Ok(())
}

/// Consecutive finite points of a series (NaN breaks the line, as "no value").
fn segments(points: &[(f64, f64)]) -> Vec<Vec<(f64, f64)>> {
    let mut out = vec![Vec::new()];
    for &(x, y) in points {
        if y.is_finite() {
            out.last_mut().expect("never empty").push((x, y));
        } else if !out.last().expect("never empty").is_empty() {
            out.push(Vec::new());
        }
    }
    out.retain(|s| !s.is_empty());
    out
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
    y_label: &str,
    y_axis: YAxis,
) -> DrawResult<DB> {
    let mut builder = ChartBuilder::on(area);
    builder
        .margin(8)
        .caption(&panel.title, ("sans-serif", 16))
        .x_label_area_size(38)
        .y_label_area_size(58);
    let (x0, x1) = panel.x_range;
    // Single points (a method's only finite value) are marked so they do not vanish.
    macro_rules! draw_lines {
        ($chart:expr, $clip:expr) => {{
            for series in &panel.series {
                for segment in segments(&series.points) {
                    let segment: Vec<(f64, f64)> = segment.into_iter().map($clip).collect();
                    if segment.len() == 1 {
                        $chart.draw_series(std::iter::once(Circle::new(
                            segment[0],
                            3,
                            series.colour.filled(),
                        )))?;
                    } else {
                        $chart.draw_series(LineSeries::new(segment, series.colour.stroke_width(2)))?;
                    }
                }
            }
        }};
    }
    match y_axis {
        YAxis::Ratio => {
            let mut chart = builder.build_cartesian_2d(x0..x1, -0.02..1.02)?;
            chart
                .configure_mesh()
                .light_line_style(WHITE.mix(0.0))
                .bold_line_style(BLACK.mix(0.08))
                .x_desc(&panel.x_label)
                .y_desc(y_label)
                .label_style(("sans-serif", 13))
                .axis_desc_style(("sans-serif", 14))
                .draw()?;
            draw_lines!(chart, |p| p);
        }
        YAxis::Log(lo, hi) => {
            let mut chart = builder.build_cartesian_2d(x0..x1, (lo..hi).log_scale())?;
            chart
                .configure_mesh()
                .light_line_style(WHITE.mix(0.0))
                .bold_line_style(BLACK.mix(0.08))
                .x_desc(&panel.x_label)
                .y_desc(y_label)
                .y_label_formatter(&|v| format!("{v:.0e}"))
                .label_style(("sans-serif", 13))
                .axis_desc_style(("sans-serif", 14))
                .draw()?;
            // Errors below the axis (exact fits) sit on its floor.
            draw_lines!(chart, |(x, y): (f64, f64)| (x, y.clamp(lo, hi)));
        }
    }
    Ok(())
}

/// The paper's Fig. 1 (right) for one fitted histogram, drawn by the CLI's `--plot` code
/// (`src/cli/plot.rs`, compiled in below): raw counts as bars, the smoothed histogram the model
/// is fitted to, the fitted inlier model G (σ + β dashed while β is not negligible) and
/// P(inlier | r) on a 0..1 axis on the right. `.svg` or `.png`, from the extension.
pub fn histogram_figure(
    path: &Path,
    title: &str,
    x_label: &str,
    model: &HistogramModel,
) -> Result<(), String> {
    let text = fig1::PlotText {
        title,
        x_label,
        panel_captions: Vec::new(),
    };
    fig1::write_plot(path, std::slice::from_ref(model), &text)
}

// One drawing of Fig. 1 for `sie register --plot` and this reproduction: the CLI's plot module
// and the two it uses, compiled into the example (the CLI is a binary, not a library, and
// plotting is no part of the library's API). Not every item of them is used here.
#[allow(dead_code)]
#[path = "../../src/cli/plot.rs"]
mod fig1;
#[allow(dead_code)]
#[path = "../../src/cli/glyphs.rs"]
mod glyphs;
#[allow(dead_code)]
#[path = "../../src/cli/numbers.rs"]
mod numbers;
