//! `path.png`/`.svg`: the run seen from above. The robot's track over the weld line, from its
//! start (a green dot) to where it stopped (a red cross), at the same scale on both axes, so
//! that a corner looks like a corner.

use std::path::Path;

use plotters::coord::Shift;
use plotters::prelude::*;

use super::ReportError;
use super::plot::{FONT_FAMILY, Figure, PALETTE, PLOT_SIZE_PX, PlotFiles, significant, write_figure};

/// The track's colour, and the line's.
pub const TRACK_RGB: (u8, u8, u8) = (PALETTE[0].0, PALETTE[0].1, PALETTE[0].2);
pub const LINE_RGB: (u8, u8, u8) = (PALETTE[7].0, PALETTE[7].1, PALETTE[7].2);
/// Room the caption and axis labels take, so that the plotting area keeps equal scales.
const CAPTION_PX: u32 = 46;
const X_LABELS_PX: u32 = 56;
const Y_LABELS_PX: u32 = 84;
const MARGIN_PX: u32 = 20;

/// Plots `track` over `line` (both (x, z) in metres, seen from above: x to the right, z down,
/// so that the robot's left is up when it drives along +x) into `out_dir/STEM.png` and `.svg`.
pub fn plot_path(out_dir: &Path, stem: &str, line: &[[f32; 2]], track: &[[f32; 2]]) -> Result<PlotFiles, ReportError> {
    write_figure(out_dir, stem, &PathPlot { line, track })
}

struct PathPlot<'a> {
    line: &'a [[f32; 2]],
    track: &'a [[f32; 2]],
}

impl Figure for PathPlot<'_> {
    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        draw(root, self.line, self.track)
    }
}

/// Ranges for (x, −z) that hold every point with a 5 % margin and give a metre the same number
/// of pixels on both axes.
fn equal_ranges(points: impl Iterator<Item = (f64, f64)>) -> (std::ops::Range<f64>, std::ops::Range<f64>) {
    let (mut x, mut y) = ((f64::INFINITY, f64::NEG_INFINITY), (f64::INFINITY, f64::NEG_INFINITY));
    for (px, py) in points.filter(|(a, b)| a.is_finite() && b.is_finite()) {
        x = (x.0.min(px), x.1.max(px));
        y = (y.0.min(py), y.1.max(py));
    }
    if x.0 > x.1 {
        return (0.0..1.0, 0.0..1.0);
    }
    let area_w = f64::from(PLOT_SIZE_PX.0 - 2 * MARGIN_PX - Y_LABELS_PX);
    let area_h = f64::from(PLOT_SIZE_PX.1 - 2 * MARGIN_PX - X_LABELS_PX - CAPTION_PX);
    let span = ((x.1 - x.0) / area_w).max((y.1 - y.0) / area_h).max(1e-3 / area_h) * 1.1;
    let (cx, cy) = ((x.0 + x.1) / 2.0, (y.0 + y.1) / 2.0);
    (cx - span * area_w / 2.0..cx + span * area_w / 2.0, cy - span * area_h / 2.0..cy + span * area_h / 2.0)
}

fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, line: &[[f32; 2]], track: &[[f32; 2]]) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    root.fill(&WHITE)?;
    // Seen from above with z pointing to the robot's right: plot −z upwards.
    let plan = |p: &[f32; 2]| (f64::from(p[0]), -f64::from(p[1]));
    let (x_range, y_range) = equal_ranges(line.iter().chain(track).map(plan));
    let mut chart = ChartBuilder::on(&root)
        .caption("Path seen from above", (FONT_FAMILY, 26))
        .margin(MARGIN_PX)
        .x_label_area_size(X_LABELS_PX)
        .y_label_area_size(Y_LABELS_PX)
        .build_cartesian_2d(x_range, y_range)?;
    chart
        .configure_mesh()
        .x_desc("x (m)")
        .y_desc("left of +x (m)")
        .x_label_formatter(&|v| significant(*v))
        .y_label_formatter(&|v| significant(*v))
        .label_style((FONT_FAMILY, 15))
        .axis_desc_style((FONT_FAMILY, 18))
        .draw()?;
    let (line_colour, track_colour) = (RGBColor(LINE_RGB.0, LINE_RGB.1, LINE_RGB.2), RGBColor(TRACK_RGB.0, TRACK_RGB.1, TRACK_RGB.2));
    chart
        .draw_series(LineSeries::new(line.iter().map(plan), line_colour.stroke_width(4)))?
        .label("weld line")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], line_colour.stroke_width(4)));
    chart
        .draw_series(LineSeries::new(track.iter().map(plan), track_colour.stroke_width(2)))?
        .label("robot")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], track_colour.stroke_width(2)));
    if let (Some(first), Some(last)) = (track.first(), track.last()) {
        chart.draw_series(std::iter::once(Circle::new(plan(first), 6, GREEN.filled())))?.label("start").legend(|(x, y)| Circle::new((x + 12, y), 5, GREEN.filled()));
        chart.draw_series(std::iter::once(Cross::new(plan(last), 7, RED.stroke_width(3))))?.label("end").legend(|(x, y)| Cross::new((x + 12, y), 5, RED.stroke_width(2)));
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperRight)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font((FONT_FAMILY, 16))
        .draw()?;
    root.present()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_axes_get_the_same_scale() {
        let (x, y) = equal_ranges([(0.0, 0.0), (3.0, 0.05)].into_iter());
        let area_w = f64::from(PLOT_SIZE_PX.0 - 2 * MARGIN_PX - Y_LABELS_PX);
        let area_h = f64::from(PLOT_SIZE_PX.1 - 2 * MARGIN_PX - X_LABELS_PX - CAPTION_PX);
        assert!(((x.end - x.start) / area_w - (y.end - y.start) / area_h).abs() < 1e-12);
        assert!(x.start < 0.0 && x.end > 3.0 && y.start < 0.0 && y.end > 0.05);
    }
}
