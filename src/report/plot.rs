//! Line plots of a run (`d(t)`, `v(t)`) and of a metric against a swept parameter, as PNG and SVG.
//!
//! Text is drawn with DejaVu Sans embedded in the library (`assets/fonts/`), registered with
//! plotters as `sans-serif`: a PNG must not depend on which fonts the machine running the
//! simulation happens to have.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::Shift;
use plotters::coord::ranged1d::ValueFormatter;
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};

use super::ReportError;
use super::atomic::write_bytes_atomically;

/// Width and height of the PNG (and the SVG's canvas) in pixels.
pub const PLOT_SIZE_PX: (u32, u32) = (1024, 640);

pub(super) const FONT_FAMILY: &str = "sans-serif";
static DEJAVU_SANS: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans.ttf");

/// Line colours, in series order (Tableau 10: distinguishable, also in greyscale print).
pub(super) const PALETTE: [RGBColor; 10] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(127, 127, 127),
    RGBColor(188, 189, 34),
    RGBColor(23, 190, 207),
];

/// One labelled line: `y[i]` against `x[i]`. Non-finite points are skipped.
#[derive(Debug, Clone, Copy)]
pub struct PlotSeries<'a> {
    pub label: &'a str,
    pub x: &'a [f64],
    pub y: &'a [f64],
}

/// Title and axis labels (with units, e.g. `d (m)`).
#[derive(Debug, Clone, Copy)]
pub struct PlotLabels<'a> {
    pub title: &'a str,
    pub x: &'a str,
    pub y: &'a str,
}

/// The two files a plot was written to.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlotFiles {
    pub png: PathBuf,
    pub svg: PathBuf,
}

/// Plots the series as lines with a legend into `out_dir/STEM.png` and `out_dir/STEM.svg`
/// (each written atomically). For time series such as the distance error of several runs.
pub fn plot_series(out_dir: &Path, stem: &str, labels: &PlotLabels<'_>, series: &[PlotSeries<'_>]) -> Result<PlotFiles, ReportError> {
    plot(out_dir, stem, labels, series, Markers::No, XAxis::Linear)
}

/// Like [`plot_series`] on a logarithmic x axis (positive x only): for distributions of times
/// that span decades, where one long outlier would squash everything else into a corner.
pub fn plot_series_log_x(out_dir: &Path, stem: &str, labels: &PlotLabels<'_>, series: &[PlotSeries<'_>]) -> Result<PlotFiles, ReportError> {
    plot(out_dir, stem, labels, series, Markers::No, XAxis::Log)
}

/// Like [`plot_series`], with a marker on every point: for a metric measured at a few values of
/// a swept parameter (e.g. speed rise time against Kp, normal compensation on and off).
pub fn plot_metric_vs_parameter(out_dir: &Path, stem: &str, labels: &PlotLabels<'_>, series: &[PlotSeries<'_>]) -> Result<PlotFiles, ReportError> {
    plot(out_dir, stem, labels, series, Markers::Yes, XAxis::Linear)
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Markers {
    No,
    Yes,
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum XAxis {
    Linear,
    Log,
}

fn plot(out_dir: &Path, stem: &str, labels: &PlotLabels<'_>, series: &[PlotSeries<'_>], markers: Markers, x_axis: XAxis) -> Result<PlotFiles, ReportError> {
    for line in series {
        if line.x.len() != line.y.len() {
            return Err(ReportError::SeriesLengthMismatch { label: line.label.to_owned(), x_len: line.x.len(), y_len: line.y.len() });
        }
    }
    write_figure(out_dir, stem, &LinePlot { labels, series, markers, x_axis })
}

/// A picture that can be drawn on any plotters backend: the PNG's and the SVG's.
pub(super) trait Figure {
    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>>;
}

/// Draws `figure` into `out_dir/STEM.png` and `out_dir/STEM.svg`, each written atomically.
pub(super) fn write_figure(out_dir: &Path, stem: &str, figure: &impl Figure) -> Result<PlotFiles, ReportError> {
    // The stem names a file inside out_dir; a separator would put it elsewhere.
    if stem.is_empty() || stem.contains(['/', '\\']) || stem == "." || stem == ".." {
        return Err(ReportError::InvalidFileStem { stem: stem.to_owned() });
    }
    register_embedded_font()?;
    let files = PlotFiles { png: out_dir.join(format!("{stem}.png")), svg: out_dir.join(format!("{stem}.svg")) };
    let plot_error = |path: &Path| {
        let path = path.to_path_buf();
        move |message: String| ReportError::Plot { path, message }
    };

    let (width, height) = PLOT_SIZE_PX;
    let mut rgb = vec![0_u8; width as usize * height as usize * 3];
    {
        let backend = BitMapBackend::with_buffer(&mut rgb, PLOT_SIZE_PX);
        figure.draw(backend.into_drawing_area()).map_err(|error| error.to_string()).map_err(plot_error(&files.png))?;
    }
    let png = encode_png(&rgb, PLOT_SIZE_PX).map_err(|source| ReportError::PngEncoding { path: files.png.clone(), source })?;
    write_bytes_atomically(&files.png, &png)?;

    let mut svg = String::new();
    {
        let backend = SVGBackend::with_string(&mut svg, PLOT_SIZE_PX);
        figure.draw(backend.into_drawing_area()).map_err(|error| error.to_string()).map_err(plot_error(&files.svg))?;
    }
    write_bytes_atomically(&files.svg, svg.as_bytes())?;
    Ok(files)
}

/// Labelled lines against a shared x axis.
struct LinePlot<'a> {
    labels: &'a PlotLabels<'a>,
    series: &'a [PlotSeries<'a>],
    markers: Markers,
    x_axis: XAxis,
}

impl Figure for LinePlot<'_> {
    fn draw<DB: DrawingBackend>(&self, root: DrawingArea<DB, Shift>) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
        draw(root, self.labels, self.series, self.markers, self.x_axis)
    }
}

fn register_embedded_font() -> Result<(), ReportError> {
    // plotters keeps registered fonts in a process-wide table; registering once is enough.
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let registered = *REGISTERED.get_or_init(|| register_font(FONT_FAMILY, FontStyle::Normal, DEJAVU_SANS).is_ok());
    if registered { Ok(()) } else { Err(ReportError::Font) }
}

fn draw<DB: DrawingBackend>(root: DrawingArea<DB, Shift>, labels: &PlotLabels<'_>, series: &[PlotSeries<'_>], markers: Markers, x_axis: XAxis) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    root.fill(&WHITE)?;
    // Markers at the first and last parameter value would be cut in half by the frame.
    let x_margin = if markers == Markers::Yes { 0.03 } else { 0.0 };
    let (x_range, y_range) = axis_ranges(series, x_margin);
    let mut builder = ChartBuilder::on(&root);
    builder.caption(labels.title, (FONT_FAMILY, 26)).margin(20).x_label_area_size(56).y_label_area_size(84);
    match x_axis {
        XAxis::Linear => lines(builder.build_cartesian_2d(x_range, y_range)?, labels, series, markers, SeriesLabelPosition::UpperRight)?,
        XAxis::Log => {
            // Only positive values have a logarithm: the axis starts at the smallest one.
            let positive = series.iter().flat_map(finite_points).map(|(x, _)| x).filter(|&x| x > 0.0).fold(f64::INFINITY, f64::min);
            let low = if positive.is_finite() { positive * 0.8 } else { 1e-3 };
            let high = x_range.end.max(low * 10.0);
            // Distributions rise to the right: the legend goes where they have not risen yet.
            lines(builder.build_cartesian_2d((low..high).log_scale(), y_range)?, labels, series, markers, SeriesLabelPosition::UpperLeft)?;
        }
    }
    root.present()
}

/// The mesh, the lines (with markers if asked) and the legend, on a chart with any kind of x
/// axis over f64.
fn lines<'a, DB: DrawingBackend + 'a, X: Ranged<ValueType = f64> + ValueFormatter<f64>>(
    mut chart: ChartContext<'a, DB, Cartesian2d<X, RangedCoordf64>>,
    labels: &PlotLabels<'_>,
    series: &[PlotSeries<'_>],
    markers: Markers,
    legend: SeriesLabelPosition,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    chart
        .configure_mesh()
        .x_desc(labels.x)
        .y_desc(labels.y)
        // plotters' default prints 2.2e-5 and 2.5e-5 alike as 0.00002.
        .y_label_formatter(&|v| significant(*v))
        .x_label_formatter(&|v| significant(*v))
        .label_style((FONT_FAMILY, 15))
        .axis_desc_style((FONT_FAMILY, 18))
        .draw()?;
    for (index, line) in series.iter().enumerate() {
        let colour = PALETTE[index % PALETTE.len()];
        let points = line_points(line);
        chart.draw_series(LineSeries::new(points.iter().copied(), colour.stroke_width(2)))?.label(line.label).legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(2)));
        if markers == Markers::Yes {
            chart.draw_series(points.iter().map(|&point| Circle::new(point, 4, colour.filled())))?;
        }
    }
    if !series.is_empty() {
        chart.configure_series_labels().position(legend).background_style(WHITE.mix(0.85)).border_style(BLACK).label_font((FONT_FAMILY, 16)).draw()?;
    }
    Ok(())
}

/// Most points a line is drawn with: the lowest and the highest of each of as many buckets as
/// the plot has pixel columns. The picture is the same as with every point, and a run of hours
/// costs no more memory (or SVG) than a short one.
const MAX_LINE_POINTS: usize = 2 * PLOT_SIZE_PX.0 as usize;

/// The finite points of `line`, thinned to [`MAX_LINE_POINTS`] (each bucket's extremes, in
/// order) when it has more.
fn line_points(line: &PlotSeries<'_>) -> Vec<(f64, f64)> {
    let n = line.x.len().min(line.y.len());
    if n <= MAX_LINE_POINTS {
        return finite_points(line).collect();
    }
    let buckets = MAX_LINE_POINTS / 2;
    let mut points = Vec::with_capacity(MAX_LINE_POINTS);
    for bucket in 0..buckets {
        // The index and value of the bucket's lowest and highest finite point.
        let mut low: Option<(usize, f64)> = None;
        let mut high = low;
        for i in bucket * n / buckets..(bucket + 1) * n / buckets {
            let (x, y) = (line.x[i], line.y[i]);
            if !(x.is_finite() && y.is_finite()) {
                continue;
            }
            if low.is_none_or(|(_, v)| y < v) {
                low = Some((i, y));
            }
            if high.is_none_or(|(_, v)| y > v) {
                high = Some((i, y));
            }
        }
        if let (Some((a, _)), Some((b, _))) = (low, high) {
            points.push((line.x[a.min(b)], line.y[a.min(b)]));
            if a != b {
                points.push((line.x[a.max(b)], line.y[a.max(b)]));
            }
        }
    }
    points
}

fn finite_points<'a>(line: &PlotSeries<'a>) -> impl Iterator<Item = (f64, f64)> + 'a {
    line.x.iter().zip(line.y).map(|(&x, &y)| (x, y)).filter(|(x, y)| x.is_finite() && y.is_finite())
}

/// The x range spanning all finite points with `x_margin` (a fraction of the span) each side,
/// and the y range with 5 % headroom so lines do not run along the frame. Without points, or
/// with a single value, a range is widened to stay valid.
fn axis_ranges(series: &[PlotSeries<'_>], x_margin: f64) -> (Range<f64>, Range<f64>) {
    let mut x = (f64::INFINITY, f64::NEG_INFINITY);
    let mut y = (f64::INFINITY, f64::NEG_INFINITY);
    for (px, py) in series.iter().flat_map(finite_points) {
        x = (x.0.min(px), x.1.max(px));
        y = (y.0.min(py), y.1.max(py));
    }
    let widen = |(low, high): (f64, f64), margin_fraction: f64| -> Range<f64> {
        if low > high {
            return 0.0..1.0;
        }
        if low == high {
            let half = if low == 0.0 { 1.0 } else { 0.1 * low.abs() };
            return low - half..high + half;
        }
        let margin = margin_fraction * (high - low);
        low - margin..high + margin
    };
    (widen(x, x_margin), widen(y, 0.05))
}

fn encode_png(rgb: &[u8], (width, height): (u32, u32)) -> Result<Vec<u8>, png::EncodingError> {
    let mut bytes = Vec::new();
    let mut encoder = png::Encoder::new(&mut bytes, width, height);
    encoder.set_color(png::ColorType::Rgb);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header()?;
    writer.write_image_data(rgb)?;
    writer.finish()?;
    Ok(bytes)
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_long_line_is_thinned_to_its_extremes_per_pixel_column() {
        let x: Vec<f64> = (0..100_000).map(f64::from).collect();
        let mut y: Vec<f64> = x.iter().map(|v| (v / 1000.0).sin()).collect();
        y[50_000] = 7.0;
        y[60_000] = f64::NAN;
        let line = PlotSeries { label: "long", x: &x, y: &y };
        let points = line_points(&line);
        assert!(points.len() <= MAX_LINE_POINTS && points.len() > MAX_LINE_POINTS / 2, "{}", points.len());
        assert!(points.contains(&(50_000.0, 7.0)), "a spike survives");
        assert!(points.windows(2).all(|w| w[0].0 < w[1].0), "in order");
        assert!(points.iter().all(|(_, y)| y.is_finite()));
    }

    use super::*;

    fn decode_png(path: &Path) -> (png::OutputInfo, Vec<u8>) {
        let file = std::io::BufReader::new(std::fs::File::open(path).expect("PNG exists"));
        let mut reader = png::Decoder::new(file).read_info().expect("a PNG header");
        let mut pixels = vec![0; reader.output_buffer_size().expect("a sane size")];
        let info = reader.next_frame(&mut pixels).expect("a PNG frame");
        (info, pixels)
    }

    #[test]
    fn a_time_plot_is_written_as_png_and_svg() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let t: Vec<f64> = (0..200).map(|i| f64::from(i) * 0.05).collect();
        let d: Vec<f64> = t.iter().map(|&ti| 0.3 * (-0.5 * ti).exp() * (2.0 * ti).cos()).collect();
        let d2: Vec<f64> = t.iter().map(|&ti| 0.3 * (-ti).exp()).collect();
        let labels = PlotLabels { title: "Distance error", x: "t (s)", y: "d (m)" };
        let series = [PlotSeries { label: "zeta = 0.2", x: &t, y: &d }, PlotSeries { label: "zeta = 1.0 & <more>", x: &t, y: &d2 }];
        let files = plot_series(dir.path(), "distance", &labels, &series).expect("plotted");
        assert_eq!(files.png, dir.path().join("distance.png"));

        let (info, pixels) = decode_png(&files.png);
        assert_eq!((info.width, info.height), PLOT_SIZE_PX);
        // Not a blank canvas: the plot drew dark text and coloured lines on white.
        assert!(pixels.chunks(3).any(|p| p[0] < 100 && p[1] < 100 && p[2] < 100));
        assert!(pixels.chunks(3).any(|p| p == [31, 119, 180]));

        let svg = std::fs::read_to_string(&files.svg).expect("SVG exists");
        assert!(svg.starts_with("<svg"), "{}", &svg[..40.min(svg.len())]);
        assert!(svg.contains("zeta = 0.2"));
        assert!(svg.contains("zeta = 1.0 &amp; &lt;more&gt;"), "labels are escaped");
        assert!(svg.contains("Distance error"));
        assert!(!dir.path().join("distance.png.tmp").exists());
    }

    #[test]
    fn a_parameter_sweep_plot_has_markers_and_series_labels() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let kp = [0.5, 1.0, 2.0, 4.0];
        let with = [1.2, 0.8, 0.5, 0.4];
        let without = [1.6, 1.1, 0.9, f64::NAN];
        let labels = PlotLabels { title: "Speed rise time", x: "Kp", y: "rise time (s)" };
        let series = [PlotSeries { label: "compensation on", x: &kp, y: &with }, PlotSeries { label: "compensation off", x: &kp, y: &without }];
        let files = plot_metric_vs_parameter(dir.path(), "rise_time_vs_kp", &labels, &series).expect("plotted");
        let (info, _) = decode_png(&files.png);
        assert_eq!((info.width, info.height), PLOT_SIZE_PX);
        let svg = std::fs::read_to_string(&files.svg).expect("SVG exists");
        assert!(svg.contains("compensation on") && svg.contains("compensation off"));
        assert!(svg.contains("<circle"), "points are marked");
    }

    #[test]
    fn mismatched_series_and_bad_stems_are_errors() {
        let dir = tempfile::tempdir().expect("temporary directory");
        let labels = PlotLabels { title: "t", x: "x", y: "y" };
        let short = [PlotSeries { label: "short", x: &[0.0, 1.0], y: &[0.0] }];
        assert!(matches!(plot_series(dir.path(), "p", &labels, &short), Err(ReportError::SeriesLengthMismatch { x_len: 2, y_len: 1, .. })));
        assert!(matches!(plot_series(dir.path(), "../p", &labels, &[]), Err(ReportError::InvalidFileStem { .. })));
    }

    #[test]
    fn degenerate_data_still_gives_valid_axes() {
        assert_eq!(axis_ranges(&[], 0.0), (0.0..1.0, 0.0..1.0));
        let one = [PlotSeries { label: "one", x: &[2.0], y: &[0.0] }];
        assert_eq!(axis_ranges(&one, 0.0), (1.8..2.2, -1.0..1.0));
        let dir = tempfile::tempdir().expect("temporary directory");
        let labels = PlotLabels { title: "empty", x: "x", y: "y" };
        plot_series(dir.path(), "empty", &labels, &[]).expect("an empty plot is still a plot");
    }
}

/// An axis label with three significant digits and no trailing zeros.
pub(super) fn significant(value: f64) -> String {
    if value == 0.0 || !value.is_finite() {
        return format!("{value}");
    }
    let decimals = (2 - value.abs().log10().floor() as i32).clamp(0, 12) as usize;
    let text = format!("{value:.decimals$}");
    if text.contains('.') { text.trim_end_matches('0').trim_end_matches('.').to_owned() } else { text }
}

#[cfg(test)]
mod label_tests {
    #[test]
    fn labels_keep_three_significant_digits() {
        assert_eq!(super::significant(0.000022), "0.000022");
        assert_eq!(super::significant(0.0000255), "0.0000255");
        assert_eq!(super::significant(12.5), "12.5");
        assert_eq!(super::significant(1500.0), "1500");
        assert_eq!(super::significant(0.0), "0");
    }
}

#[cfg(test)]
mod log_axis_tests {
    #[test]
    fn a_log_time_axis_keeps_sub_millisecond_and_second_values_apart() {
        let dir = std::env::temp_dir().join(format!("climbsim-log-axis-{}", std::process::id()));
        std::fs::create_dir_all(&dir).expect("dir");
        // A zero (no logarithm) is left out, not an error.
        let x = [0.0, 0.2, 0.5, 0.9, 1.2, 2000.0];
        let y = [0.0, 0.2, 0.5, 0.9, 0.99, 1.0];
        let labels = super::PlotLabels { title: "t", x: "time (ms, log scale)", y: "fraction" };
        let files = super::plot_series_log_x(&dir, "cdf", &labels, &[super::PlotSeries { label: "reply", x: &x, y: &y }]).expect("plot");
        let svg = std::fs::read_to_string(&files.svg).expect("svg");
        // Decade ticks from below the fastest reply to beyond the outlier.
        // Each label's text is on the line after its <text> tag.
        let texts: Vec<&str> = svg.lines().map(str::trim).collect();
        for tick in ["1", "10", "100", "1000"] {
            assert!(texts.contains(&tick), "no tick {tick} on the log axis: {texts:?}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}
