//! Convergence plots: relative MSE against time or rays, log-log, as PNG.
//!
//! Drawn with plotters into an in-memory RGB buffer and encoded by
//! [`crate::image_io::write_rgb8_png`], so the file is written atomically
//! like every other image. Text uses DejaVu Sans, embedded in the library
//! (`assets/fonts/`) and registered with plotters' `ab_glyph` backend: no
//! system font library or installed font is needed.
//!
//! The convergence log this module reads is a CSV with the header
//! [`CONVERGENCE_CSV_HEADER`] (`time_s,rays,spp,rel_mse`); `rel_mse` is empty
//! on rows logged without a reference, and those rows are skipped.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use image::RgbImage;
use plotters::prelude::*;
use plotters::style::{register_font, FontStyle};

use crate::image_io::{write_rgb8_png, ImageIoError};

/// DejaVu Sans 2.37 (Bitstream Vera licence, see `assets/fonts/`).
static FONT: &[u8] = include_bytes!("../assets/fonts/DejaVuSans.ttf");

/// The family name the font is registered under: plotters' own default for
/// axis labels and legends, so every piece of text finds it.
const FONT_FAMILY: &str = "sans-serif";

/// The header line of a convergence log.
pub const CONVERGENCE_CSV_HEADER: &str = "time_s,rays,spp,rel_mse";

/// An error while plotting or reading a convergence log.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// No series had a point that a log-log plot can show (x > 0, y > 0,
    /// both finite).
    #[error("nothing to plot: no point with positive finite x and y")]
    NoData,
    /// The plot size is zero.
    #[error("plot size {0}×{1} is empty")]
    BadSize(u32, u32),
    /// The embedded font could not be loaded.
    #[error("the embedded font could not be registered")]
    Font,
    /// plotters failed while drawing.
    #[error("drawing the plot failed: {0}")]
    Draw(String),
    /// Writing the PNG failed.
    #[error(transparent)]
    Write(#[from] ImageIoError),
    /// The convergence log could not be read.
    #[error("{path}: {source}", path = .path.display())]
    Io {
        /// The file.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The convergence log is malformed.
    #[error("{path}:{line}: {reason}", path = .path.display())]
    Csv {
        /// The file.
        path: PathBuf,
        /// Line number, from 1.
        line: usize,
        /// What was wrong.
        reason: String,
    },
}

/// One curve: a label for the legend and (x, y) points.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Series {
    /// Legend text (none shown when empty).
    pub label: String,
    /// Points (x, y); those a log-log plot cannot show (non-positive or
    /// non-finite) are left out.
    pub points: Vec<(f64, f64)>,
}

/// What the x axis of a convergence plot measures.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum XAxis {
    /// Wall-clock seconds (`time_s`).
    #[default]
    TimeSeconds,
    /// Rays traced (`rays`): the papers compare methods at equal ray counts.
    Rays,
    /// Samples (or particles) per pixel (`spp`).
    Spp,
}

impl XAxis {
    /// The axis description.
    pub fn label(self) -> &'static str {
        match self {
            XAxis::TimeSeconds => "time (s)",
            XAxis::Rays => "rays traced",
            XAxis::Spp => "samples per pixel",
        }
    }
}

/// Size and text of a plot.
#[derive(Clone, Debug, PartialEq)]
pub struct PlotOptions {
    /// Title above the plot (none when empty).
    pub title: String,
    /// Description of the x axis.
    pub x_label: String,
    /// Description of the y axis.
    pub y_label: String,
    /// Width in pixels.
    pub width: u32,
    /// Height in pixels.
    pub height: u32,
}

impl Default for PlotOptions {
    fn default() -> Self {
        PlotOptions {
            title: String::new(),
            x_label: XAxis::TimeSeconds.label().into(),
            y_label: "relative MSE".into(),
            width: 800,
            height: 600,
        }
    }
}

impl PlotOptions {
    /// The defaults, with the x description for `x`.
    pub fn for_axis(x: XAxis) -> Self {
        PlotOptions {
            x_label: x.label().into(),
            ..Default::default()
        }
    }
}

fn ensure_font() -> Result<(), PlotError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok =
        *REGISTERED.get_or_init(|| register_font(FONT_FAMILY, FontStyle::Normal, FONT).is_ok());
    if ok {
        Ok(())
    } else {
        Err(PlotError::Font)
    }
}

fn draw_err<E: std::fmt::Display>(e: E) -> PlotError {
    PlotError::Draw(e.to_string())
}

/// A tick label: plain for "ordinary" magnitudes, scientific otherwise.
fn tick_label(v: f64) -> String {
    let a = v.abs();
    if a == 0.0 || (1e-2..1e4).contains(&a) {
        // Up to three significant digits, trailing zeros dropped.
        let s = format!("{:.3}", v);
        let s = s.trim_end_matches('0').trim_end_matches('.');
        s.to_string()
    } else {
        format!("{v:.0e}")
    }
}

/// The range [lo, hi] of `values` widened by the factor `pad` on each side
/// in log space. plotters labels a log axis at powers of ten, so a range
/// holding fewer than two of them is widened to the enclosing decades, or
/// the axis would carry one label or none.
fn log_range(values: impl Iterator<Item = f64>, pad: f64) -> Option<(f64, f64)> {
    let (lo, hi) = values.fold((f64::INFINITY, 0.0f64), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    if !(lo.is_finite() && hi > 0.0) {
        return None;
    }
    let (lo, hi) = (lo / pad, hi * pad);
    let (k_lo, k_hi) = (lo.log10(), hi.log10());
    if k_hi.floor() - k_lo.ceil() < 1.0 {
        return Some((10f64.powf(k_lo.floor()), 10f64.powf(k_hi.ceil())));
    }
    Some((lo, hi))
}

/// Draws `series` on log-log axes (x: time, rays or spp; y: relative MSE)
/// into the PNG `out`, written atomically.
pub fn plot_convergence(
    series: &[Series],
    out: &Path,
    opts: &PlotOptions,
) -> Result<(), PlotError> {
    let (w, h) = (opts.width, opts.height);
    if w == 0 || h == 0 {
        return Err(PlotError::BadSize(w, h));
    }
    ensure_font()?;

    // Keep only the points a log-log plot can show.
    let shown: Vec<(&str, Vec<(f64, f64)>)> = series
        .iter()
        .map(|s| {
            let pts = s
                .points
                .iter()
                .copied()
                .filter(|&(x, y)| x.is_finite() && y.is_finite() && x > 0.0 && y > 0.0)
                .collect();
            (s.label.as_str(), pts)
        })
        .collect();
    let all = || shown.iter().flat_map(|(_, p)| p.iter().copied());
    let (x0, x1) = log_range(all().map(|p| p.0), 1.1).ok_or(PlotError::NoData)?;
    let (y0, y1) = log_range(all().map(|p| p.1), 1.5).ok_or(PlotError::NoData)?;

    let mut buf = vec![0u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(draw_err)?;

        // Set up the axes.
        let mut builder = ChartBuilder::on(&root);
        builder
            .margin(16)
            .x_label_area_size(48)
            .y_label_area_size(72);
        if !opts.title.is_empty() {
            builder.caption(&opts.title, (FONT_FAMILY, 22));
        }
        let mut chart = builder
            .build_cartesian_2d((x0..x1).log_scale(), (y0..y1).log_scale())
            .map_err(draw_err)?;
        chart
            .configure_mesh()
            .x_desc(opts.x_label.as_str())
            .y_desc(opts.y_label.as_str())
            .x_label_formatter(&|v| tick_label(*v))
            .y_label_formatter(&|v| format!("{v:.0e}"))
            .label_style((FONT_FAMILY, 14))
            .axis_desc_style((FONT_FAMILY, 16))
            .light_line_style(RGBColor(235, 235, 235))
            .bold_line_style(RGBColor(200, 200, 200))
            .draw()
            .map_err(draw_err)?;

        // One line with markers per series (markers keep single points
        // visible).
        let mut any_label = false;
        for (i, (label, pts)) in shown.iter().enumerate() {
            if pts.is_empty() {
                continue;
            }
            let color = Palette99::pick(i).to_rgba();
            let drawn = chart
                .draw_series(LineSeries::new(pts.iter().copied(), color.stroke_width(2)))
                .map_err(draw_err)?;
            if !label.is_empty() {
                any_label = true;
                drawn.label(*label).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(2))
                });
            }
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 3, color.filled())))
                .map_err(draw_err)?;
        }
        if any_label {
            chart
                .configure_series_labels()
                .position(SeriesLabelPosition::UpperRight)
                .label_font((FONT_FAMILY, 14))
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .draw()
                .map_err(draw_err)?;
        }
        root.present().map_err(draw_err)?;
    }

    let img = RgbImage::from_raw(w, h, buf).ok_or(PlotError::BadSize(w, h))?;
    write_rgb8_png(out, &img)?;
    Ok(())
}

/// One row of a convergence log that has a relative MSE.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ConvergenceRow {
    /// Wall-clock seconds since the render started.
    pub time_s: f64,
    /// Rays traced so far.
    pub rays: f64,
    /// Samples (or particles) per pixel so far.
    pub spp: f64,
    /// Relative MSE against the reference at that moment.
    pub rel_mse: f64,
}

impl ConvergenceRow {
    /// The point (x, relative MSE) for the chosen x axis.
    pub fn point(&self, x: XAxis) -> (f64, f64) {
        let x = match x {
            XAxis::TimeSeconds => self.time_s,
            XAxis::Rays => self.rays,
            XAxis::Spp => self.spp,
        };
        (x, self.rel_mse)
    }
}

/// Reads a convergence log (see the module docs). Rows whose `rel_mse` is
/// empty are skipped; columns are found by name in the header, so extra
/// columns are allowed, but the four of [`CONVERGENCE_CSV_HEADER`] must be
/// there.
pub fn read_convergence_csv(path: &Path) -> Result<Vec<ConvergenceRow>, PlotError> {
    let text = std::fs::read_to_string(path).map_err(|source| PlotError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    parse_convergence_csv(&text).map_err(|(line, reason)| PlotError::Csv {
        path: path.to_path_buf(),
        line,
        reason,
    })
}

/// Reads a convergence log into a [`Series`] with x as chosen.
pub fn series_from_csv(path: &Path, label: &str, x: XAxis) -> Result<Series, PlotError> {
    Ok(Series {
        label: label.to_string(),
        points: read_convergence_csv(path)?
            .iter()
            .map(|r| r.point(x))
            .collect(),
    })
}

/// Parses the text of a convergence log; the error is (line from 1, reason).
pub fn parse_convergence_csv(text: &str) -> Result<Vec<ConvergenceRow>, (usize, String)> {
    let mut lines = text
        .lines()
        .enumerate()
        .map(|(i, l)| (i + 1, l.trim()))
        .filter(|(_, l)| !l.is_empty());

    // Locate the columns by name.
    let (hline, header) = lines
        .next()
        .ok_or((1, "empty file, no header".to_string()))?;
    let names: Vec<&str> = header
        .trim_start_matches('\u{feff}')
        .split(',')
        .map(str::trim)
        .collect();
    let column = |name: &str| -> Result<usize, (usize, String)> {
        let mut found = names.iter().enumerate().filter(|(_, n)| **n == name);
        match (found.next(), found.next()) {
            (Some((i, _)), None) => Ok(i),
            (None, _) => Err((
                hline,
                format!("header has no `{name}` column (expected `{CONVERGENCE_CSV_HEADER}`)"),
            )),
            (Some(_), Some(_)) => Err((hline, format!("header names `{name}` twice"))),
        }
    };
    let cols = [
        column("time_s")?,
        column("rays")?,
        column("spp")?,
        column("rel_mse")?,
    ];

    // Read the rows, skipping those without a relative MSE.
    let mut rows = Vec::new();
    for (line, l) in lines {
        let fields: Vec<&str> = l.split(',').map(str::trim).collect();
        if fields.len() != names.len() {
            return Err((
                line,
                format!("{} fields, the header has {}", fields.len(), names.len()),
            ));
        }
        if fields[cols[3]].is_empty() {
            continue;
        }
        let mut v = [0.0f64; 4];
        for (k, &c) in cols.iter().enumerate() {
            v[k] = fields[c].parse().map_err(|_| {
                (
                    line,
                    format!("`{}` is not a number (column `{}`)", fields[c], names[c]),
                )
            })?;
        }
        rows.push(ConvergenceRow {
            time_s: v[0],
            rays: v[1],
            spp: v[2],
            rel_mse: v[3],
        });
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn csv_skips_rows_without_rel_mse_and_reports_lines() {
        let text = "time_s,rays,spp,rel_mse\n0.5,1000,1,\n1.0,2000,2,0.25\n\n2.0,4000,4,0.125\n";
        let rows = parse_convergence_csv(text).unwrap();
        assert_eq!(rows.len(), 2);
        assert_eq!(rows[0].point(XAxis::TimeSeconds), (1.0, 0.25));
        assert_eq!(rows[1].point(XAxis::Rays), (4000.0, 0.125));
        assert_eq!(rows[1].point(XAxis::Spp), (4.0, 0.125));

        let err = parse_convergence_csv("time_s,rays,spp,rel_mse\n1,2,3,x\n").unwrap_err();
        assert_eq!(err.0, 2);
        let err = parse_convergence_csv("time_s,rays,rel_mse\n").unwrap_err();
        assert!(err.1.contains("spp"), "{}", err.1);
        assert!(parse_convergence_csv("time_s,rays,spp,rel_mse\n1,2,3\n").is_err());
    }

    #[test]
    fn log_ranges_hold_two_decades_of_labels() {
        assert_eq!(log_range([2e5, 8e5].into_iter(), 1.1), Some((1e5, 1e6)));
        assert_eq!(log_range([1.0].into_iter(), 1.5), Some((0.1, 10.0)));
        let (lo, hi) = log_range([1.0, 128.0].into_iter(), 1.1).unwrap();
        assert!((lo - 1.0 / 1.1).abs() < 1e-12 && (hi - 128.0 * 1.1).abs() < 1e-9);
        assert_eq!(log_range(std::iter::empty(), 1.1), None);
    }

    #[test]
    fn tick_labels() {
        assert_eq!(tick_label(1.0), "1");
        assert_eq!(tick_label(0.5), "0.5");
        assert_eq!(tick_label(100.0), "100");
        assert_eq!(tick_label(1e6), "1e6");
    }
}
