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

/// The terrain's height on a regular grid over (x, z), seen from above, for shading.
#[derive(Debug, Clone, PartialEq)]
pub struct HeightGrid {
    /// The grid's corners (m): cell centres run from `x_m.0` to `x_m.1` and `z_m.0` to `z_m.1`.
    pub x_m: (f32, f32),
    pub z_m: (f32, f32),
    pub cols: usize,
    pub rows: usize,
    /// `heights[row * cols + col]` (m); NaN where there is no terrain below.
    pub heights: Vec<f32>,
}

impl HeightGrid {
    /// The lowest and highest known height.
    pub fn range(&self) -> Option<(f32, f32)> {
        let (low, high) = self.heights.iter().filter(|h| h.is_finite()).fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &h| (lo.min(h), hi.max(h)));
        (low <= high).then_some((low, high))
    }
}

/// Heights that differ by less than this (m) are drawn as flat ground: no shading.
const FLAT_M: f32 = 1e-4;
/// Shades of the height ramp (cells of one shade next to each other are drawn as one).
const SHADES: usize = 16;
/// The ramp's ends, low and high: pale sand to a darker khaki, away from the line's grey and
/// the track's blue.
const LOW_RGB: (f64, f64, f64) = (246.0, 243.0, 232.0);
const HIGH_RGB: (f64, f64, f64) = (196.0, 184.0, 140.0);

/// How the path picture looks at the ground.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum PathView {
    /// From above: (x, z) of the world.
    #[default]
    FromAbove,
    /// A wall terrain laid flat: x along the surface (floor, fillet, wall), z across.
    LaidFlat,
}

/// Plots `track` over `line` (both (x, z) in metres, seen from above: x to the right, z down,
/// so that the robot's left is up when it drives along +x) into `out_dir/STEM.png` and `.svg`,
/// over the terrain's height (`heights`) when it is given and not flat.
pub fn plot_path(out_dir: &Path, stem: &str, lines: &[Vec<[f32; 2]>], track: &[[f32; 2]], heights: Option<&HeightGrid>, view: PathView) -> Result<PlotFiles, ReportError> {
    write_figure(out_dir, stem, &PathPlot { lines, track, heights, view })
}

struct PathPlot<'a> {
    /// The weld lines (a scenario's `[line]`, then its `[[welds]]`).
    lines: &'a [Vec<[f32; 2]>],
    track: &'a [[f32; 2]],
    heights: Option<&'a HeightGrid>,
    view: PathView,
}

impl Figure for PathPlot<'_> {
    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        draw(root, self)
    }
}

/// The shade (0 = lowest) of each cell, `None` where the height is unknown.
fn shade_of(height: f32, (low, high): (f32, f32)) -> Option<usize> {
    height.is_finite().then(|| ((((height - low) / (high - low)) * SHADES as f32) as usize).min(SHADES - 1))
}

fn shade_colour(shade: usize) -> RGBColor {
    let f = shade as f64 / (SHADES - 1) as f64;
    let mix = |a: f64, b: f64| (a + (b - a) * f).round() as u8;
    RGBColor(mix(LOW_RGB.0, HIGH_RGB.0), mix(LOW_RGB.1, HIGH_RGB.1), mix(LOW_RGB.2, HIGH_RGB.2))
}

/// Runs of cells of one shade along x, as plan rectangles ((x0, −z0), (x1, −z1)) and shade.
fn shaded_runs(grid: &HeightGrid, range: (f32, f32)) -> Vec<([(f64, f64); 2], usize)> {
    let step = |(a, b): (f32, f32), n: usize| if n > 1 { f64::from(b - a) / (n - 1) as f64 } else { 1.0 };
    let (dx, dz) = (step(grid.x_m, grid.cols), step(grid.z_m, grid.rows));
    let x_at = |col: usize| f64::from(grid.x_m.0) + dx * col as f64;
    let z_at = |row: usize| f64::from(grid.z_m.0) + dz * row as f64;
    let mut runs = Vec::new();
    for row in 0..grid.rows {
        let mut col = 0;
        while col < grid.cols {
            let Some(shade) = grid.heights.get(row * grid.cols + col).and_then(|&h| shade_of(h, range)) else {
                col += 1;
                continue;
            };
            let start = col;
            while col + 1 < grid.cols && grid.heights.get(row * grid.cols + col + 1).and_then(|&h| shade_of(h, range)) == Some(shade) {
                col += 1;
            }
            let (z0, z1) = (z_at(row) - dz / 2.0, z_at(row) + dz / 2.0);
            runs.push(([(x_at(start) - dx / 2.0, -z0), (x_at(col) + dx / 2.0, -z1)], shade));
            col += 1;
        }
    }
    runs
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

fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, plot: &PathPlot<'_>) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let PathPlot { lines, track, heights, view } = *plot;
    root.fill(&WHITE)?;
    // Seen from above with z pointing to the robot's right: plot −z upwards.
    let plan = |p: &[f32; 2]| (f64::from(p[0]), -f64::from(p[1]));
    let (x_range, y_range) = equal_ranges(lines.iter().flatten().chain(track).map(plan));
    let shading = heights.and_then(|grid| grid.range().filter(|(low, high)| high - low >= FLAT_M).map(|range| (grid, range)));
    let caption = match shading {
        // `+ 0.0` turns a rounded −0 into 0.
        Some((_, (low, high))) => format!("Path seen from above (terrain {} to {} mm, darker higher)", (low * 1000.0).round() + 0.0, (high * 1000.0).round() + 0.0),
        None if view == PathView::LaidFlat => "Path on the surface laid flat (floor, fillet, wall)".to_owned(),
        None => "Path seen from above".to_owned(),
    };
    let x_desc = if view == PathView::LaidFlat { "x along the surface (m)" } else { "x (m)" };
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, (FONT_FAMILY, 26))
        .margin(MARGIN_PX)
        .x_label_area_size(X_LABELS_PX)
        .y_label_area_size(Y_LABELS_PX)
        .build_cartesian_2d(x_range.clone(), y_range.clone())?;
    // The terrain first: the grid lines and the path go over it.
    if let Some((grid, range)) = shading {
        // Cut to the plotting area: cells outside it would paint over the axes.
        let (xs, ys) = (x_range.clone(), y_range.clone());
        let clip = move |[(x0, y0), (x1, y1)]: [(f64, f64); 2]| {
            let (lo_x, hi_x) = (x0.min(x1).max(xs.start), x0.max(x1).min(xs.end));
            let (lo_y, hi_y) = (y0.min(y1).max(ys.start), y0.max(y1).min(ys.end));
            (lo_x < hi_x && lo_y < hi_y).then_some([(lo_x, lo_y), (hi_x, hi_y)])
        };
        chart.draw_series(shaded_runs(grid, range).into_iter().filter_map(|(corners, shade)| clip(corners).map(|c| Rectangle::new(c, shade_colour(shade).filled()))))?;
    }
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc("left of +x (m)")
        .x_label_formatter(&|v| significant(*v))
        .y_label_formatter(&|v| significant(*v))
        .label_style((FONT_FAMILY, 15))
        .axis_desc_style((FONT_FAMILY, 18))
        .draw()?;
    let (line_colour, track_colour) = (RGBColor(LINE_RGB.0, LINE_RGB.1, LINE_RGB.2), RGBColor(TRACK_RGB.0, TRACK_RGB.1, TRACK_RGB.2));
    for (k, line) in lines.iter().enumerate() {
        let series = chart.draw_series(LineSeries::new(line.iter().map(plan), line_colour.stroke_width(4)))?;
        if k == 0 {
            series.label(if lines.len() > 1 { "welds" } else { "weld line" }).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], line_colour.stroke_width(4)));
        }
    }
    chart
        .draw_series(LineSeries::new(track.iter().map(plan), track_colour.stroke_width(2)))?
        .label("robot")
        .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], track_colour.stroke_width(2)));
    if let (Some(first), Some(last)) = (track.first(), track.last()) {
        chart.draw_series(std::iter::once(Circle::new(plan(first), 6, GREEN.filled())))?.label("start").legend(|(x, y)| Circle::new((x + 12, y), 5, GREEN.filled()));
        chart.draw_series(std::iter::once(Cross::new(plan(last), 7, RED.stroke_width(3))))?.label("end").legend(|(x, y)| Cross::new((x + 12, y), 5, RED.stroke_width(2)));
    }
    chart.configure_series_labels().position(SeriesLabelPosition::UpperRight).background_style(WHITE.mix(0.85)).border_style(BLACK).label_font((FONT_FAMILY, 16)).draw()?;
    root.present()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn runs_of_one_shade_merge_and_unknown_cells_are_left_blank() {
        let grid = HeightGrid { x_m: (0.0, 3.0), z_m: (0.0, 1.0), cols: 4, rows: 2, heights: vec![0.0, 0.0, 0.01, f32::NAN, 0.0, 0.0, 0.0, 0.0] };
        let runs = shaded_runs(&grid, grid.range().expect("range"));
        // Row 0: two low cells, one high, one unknown; row 1: four low cells in one run.
        assert_eq!(runs.iter().map(|(_, shade)| *shade).collect::<Vec<_>>(), vec![0, SHADES - 1, 0]);
        let [(x0, _), (x1, _)] = runs[2].0;
        assert!((x0 + 0.5).abs() < 1e-9 && (x1 - 3.5).abs() < 1e-9, "{:?}", runs[2]);
        assert_ne!(shade_colour(0), shade_colour(SHADES - 1));
    }

    #[test]
    fn both_axes_get_the_same_scale() {
        let (x, y) = equal_ranges([(0.0, 0.0), (3.0, 0.05)].into_iter());
        let area_w = f64::from(PLOT_SIZE_PX.0 - 2 * MARGIN_PX - Y_LABELS_PX);
        let area_h = f64::from(PLOT_SIZE_PX.1 - 2 * MARGIN_PX - X_LABELS_PX - CAPTION_PX);
        assert!(((x.end - x.start) / area_w - (y.end - y.start) / area_h).abs() < 1e-12);
        assert!(x.start < 0.0 && x.end > 3.0 && y.start < 0.0 && y.end > 0.05);
    }
}
