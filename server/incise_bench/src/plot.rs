//! The speed-vs-error plot (log-log, one series per model, and on the liver per model and element
//! kind) drawn with `plotters` into a PNG, with the peers as labelled markers: measured on this
//! machine at their error (`--peers`), or else their published speeds on scene B
//! (docs/benchmarks.md, first run) in a band above 100 % error. With liver rows, two fronts: the
//! fastest configuration at each error with condensed elements only, and with every kind.

use plotters::prelude::*;
use plotters::style::{FontStyle, register_font};
use std::path::Path;

/// Where Debian's `fonts-dejavu-core` puts the font the labels use.
const FONT: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";

/// Peers' steps/s at dt = 1 ms on B1–B3 (docs/benchmarks.md, first run); their error is not published.
const PEERS: [(&str, [f64; 3]); 3] = [
    ("MuJoCo implicit", [738.0, 171.0, 22.2]),
    ("MuJoCo explicit", [3_128.0, 916.0, 126.0]),
    ("Newton semi-implicit", [5_116.0, 2_274.0, 455.0]),
];

/// Height of a label line (px) at the labels' 11 px font.
const LINE: i32 = 13;

/// Whether two pixel boxes `[x0, y0, x1, y1]` overlap.
fn overlap(a: &[i32; 4], b: &[i32; 4]) -> bool {
    a[0] < b[2] && b[0] < a[2] && a[1] < b[3] && b[1] < a[3]
}

fn load_font() -> anyhow::Result<()> {
    let bytes = std::fs::read(FONT)
        .map_err(|e| anyhow::anyhow!("{FONT}: {e} (install Debian's fonts-dejavu-core)"))?;
    register_font("sans-serif", FontStyle::Normal, Box::leak(bytes.into_boxed_slice()))
        .map_err(|_| anyhow::anyhow!("{FONT} is not a usable TrueType font"))?;
    Ok(())
}

/// One row of the report as the plot sees it.
pub struct Point<'a> {
    pub model: &'a str,
    pub element: &'a str,
    pub scene: &'a str,
    pub steps_per_s: f64,
    pub error: Option<f64>,
    pub stable: bool,
}

impl Point<'_> {
    fn is_liver(&self) -> bool {
        self.scene.starts_with("liver")
    }

    /// The series the point is drawn in.
    fn series(&self) -> String {
        if self.is_liver() {
            format!("{}, {}", self.model, self.element)
        } else {
            self.model.to_owned()
        }
    }
}

/// The Pareto front of `(steps/s, error)` points: from the fastest down, each point with a lower
/// error than every faster one.
fn front(mut points: Vec<(f64, f64)>) -> Vec<(f64, f64)> {
    points.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut best = f64::INFINITY;
    points
        .into_iter()
        .filter(|&(_, e)| {
            let better = e < best;
            best = best.min(e);
            better
        })
        .collect()
}

/// Draws `points` to `path`, and the `measured` peers' `(label, steps/s, error)` points (or,
/// without them, the published speeds on scene B when scene B is drawn).
pub fn speed_error_png(
    path: &Path,
    points: &[Point<'_>],
    measured: Option<&[(String, f64, f64)]>,
) -> anyhow::Result<()> {
    load_font()?;
    let usable: Vec<(&Point<'_>, f64, f64)> = points
        .iter()
        .filter_map(|p| {
            let e = p.error.filter(|&e| e > 0.0)?;
            (p.stable && p.steps_per_s > 0.0).then_some((p, p.steps_per_s, e))
        })
        .collect();
    let published = measured.is_none() && points.iter().any(|p| p.scene.starts_with('B'));
    let (mut x_lo, mut x_hi) = (1.0f64, 1e4f64);
    let (mut y_lo, mut y_hi) = (1e-3f64, 1.0f64);
    let peer_points = measured.unwrap_or_default().iter().map(|(_, s, e)| (*s, *e));
    for (s, e) in usable.iter().map(|&(_, s, e)| (s, e)).chain(peer_points) {
        x_lo = x_lo.min(s / 2.0);
        x_hi = x_hi.max(s * 2.0);
        y_lo = y_lo.min(e / 2.0);
        y_hi = y_hi.max(e * 2.0);
    }
    // Without measured peers, the published speeds sit in a band above 100 % error, where no
    // measured point can be.
    let band = y_hi.max(1.0) * 1.2;
    let y_hi = if published { band * 1.25f64.powi(10) } else { y_hi };
    let root = BitMapBackend::new(path, (1000, 700)).into_drawing_area();
    root.fill(&WHITE)?;
    let mut chart = ChartBuilder::on(&root)
        .caption("incise: speed against error (stable configurations)", ("sans-serif", 24))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d((x_lo..x_hi).log_scale(), (y_lo..y_hi).log_scale())?;
    chart
        .configure_mesh()
        .x_desc("steps per second")
        .y_desc("relative error")
        .label_style(("sans-serif", 14))
        .draw()?;
    let mut names: Vec<String> = Vec::new();
    for (p, ..) in &usable {
        if !names.contains(&p.series()) {
            names.push(p.series());
        }
    }
    for (i, name) in names.iter().enumerate() {
        let color = Palette99::pick(i).to_rgba();
        let series: Vec<(f64, f64)> =
            usable.iter().filter(|p| p.0.series() == *name).map(|p| (p.1, p.2)).collect();
        chart
            .draw_series(series.iter().map(|&(x, y)| Circle::new((x, y), 5, color.filled())))?
            .label(name.clone())
            .legend(move |(x, y)| Circle::new((x, y), 5, color.filled()));
    }
    let liver = |condensed_only: bool| {
        front(
            usable
                .iter()
                .filter(|p| p.0.is_liver() && (!condensed_only || p.0.element == "condensed"))
                .map(|p| (p.1, p.2))
                .collect(),
        )
    };
    for (label, line, width) in [
        ("liver front, condensed elements", liver(true), 1),
        ("liver front, every element kind", liver(false), 3),
    ] {
        if line.len() > 1 {
            let style = BLACK.stroke_width(width);
            chart
                .draw_series(LineSeries::new(line, style))?
                .label(label)
                .legend(move |(x, y)| PathElement::new(vec![(x - 8, y), (x + 8, y)], style));
        }
    }
    if let Some(measured) = measured {
        let color = Palette99::pick(6).to_rgba();
        // Peers often sit close together: each label goes right of its marker, moved down a
        // line at a time until it clears the labels already placed, with a leader line when
        // moved.
        let mut placed: Vec<[i32; 4]> = Vec::new();
        for (label, rate, error) in measured {
            let at = (*rate, *error);
            chart.draw_series(std::iter::once(TriangleMarker::new(at, 7, color.filled())))?;
            let (px, py) = chart.backend_coord(&at);
            let (width, height) = (6 * label.chars().count() as i32, LINE);
            let mut dy = -height / 2;
            for _ in 0..30 {
                let bounds = [px + 8, py + dy, px + 8 + width, py + dy + height];
                if !placed.iter().any(|b| overlap(b, &bounds)) {
                    break;
                }
                dy += height;
            }
            placed.push([px + 8, py + dy, px + 8 + width, py + dy + height]);
            let text = Text::new(label.clone(), (8, dy), ("sans-serif", 11));
            if dy == -height / 2 {
                chart.draw_series(std::iter::once(EmptyElement::at(at) + text))?;
            } else {
                let leader = PathElement::new(vec![(0, 0), (8, dy + height / 2)], color);
                chart.draw_series(std::iter::once(EmptyElement::at(at) + leader + text))?;
            }
        }
    } else if published {
        for (k, (name, rates)) in PEERS.iter().enumerate() {
            let color = Palette99::pick(k + 6).to_rgba();
            for (b, &rate) in rates.iter().enumerate() {
                if rate > x_lo && rate < x_hi {
                    // Their error is not published: they sit in a band at the top, at their speed only.
                    // One row per (peer, scene) so the labels do not overlap.
                    let top = band * 1.25f64.powi((3 * k + b) as i32);
                    chart.draw_series(std::iter::once(TriangleMarker::new(
                        (rate, top),
                        7,
                        color.filled(),
                    )))?;
                    chart.draw_series(std::iter::once(Text::new(
                        format!("{name} B{} (speed only)", b + 1),
                        (rate, top),
                        ("sans-serif", 11),
                    )))?;
                }
            }
        }
        chart.draw_series(std::iter::once(Text::new(
            "peers: published speed only (docs/benchmarks.md, first run); their error is not published",
            (x_lo * 1.1, band / 1.1),
            ("sans-serif", 12),
        )))?;
    }
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;
    root.present()?;
    Ok(())
}
