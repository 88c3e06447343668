//! Error against run time as an SVG scatter plot, with the Pareto front marked. Written by
//! hand (a few dozen SVG elements) so the picture needs no font or drawing library.

use crate::error::Result;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::Path;

/// One point of the plot.
#[derive(Debug, Clone, PartialEq)]
pub struct PlotPoint {
    /// Series (one colour each), e.g. "mvao horizon".
    pub series: String,
    /// Short label drawn next to the point, e.g. "8×8 N=3".
    pub label: String,
    /// Wall time in seconds (x, log scale).
    pub seconds: f64,
    /// Error (y).
    pub error: f64,
}

/// Indices of the points on the Pareto front (no other point is both faster and more
/// accurate), sorted by time.
pub fn pareto_front(points: &[PlotPoint]) -> Vec<usize> {
    let mut idx: Vec<usize> = (0..points.len())
        .filter(|&i| points[i].seconds.is_finite() && points[i].error.is_finite())
        .collect();
    idx.sort_by(|&a, &b| {
        points[a]
            .seconds
            .total_cmp(&points[b].seconds)
            .then(points[a].error.total_cmp(&points[b].error))
    });
    let mut front = Vec::new();
    let mut best = f64::INFINITY;
    for i in idx {
        if points[i].error < best {
            best = points[i].error;
            front.push(i);
        }
    }
    front
}

const PALETTE: [&str; 8] = [
    "#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf",
];

fn esc(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
        .replace('"', "&quot;")
}

/// Writes the plot to `path` (SVG, atomically).
pub fn write_svg(path: &Path, title: &str, y_name: &str, points: &[PlotPoint]) -> Result<()> {
    let svg = render_svg(title, y_name, points);
    crate::io::atomic::write_atomic(path, |w| w.write_all(svg.as_bytes()))
}

/// The plot as an SVG document.
pub fn render_svg(title: &str, y_name: &str, points: &[PlotPoint]) -> String {
    let (w, h) = (900.0f64, 600.0f64);
    let (l, r, t, b) = (80.0, 220.0, 50.0, 60.0);
    let (pw, ph) = (w - l - r, h - t - b);
    let good: Vec<&PlotPoint> = points
        .iter()
        .filter(|p| p.seconds.is_finite() && p.seconds > 0.0 && p.error.is_finite())
        .collect();
    let (mut x0, mut x1) = good
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| {
            (a.min(p.seconds.log10()), b.max(p.seconds.log10()))
        });
    if !x0.is_finite() {
        (x0, x1) = (-1.0, 1.0);
    }
    x0 = x0.floor();
    x1 = x1.ceil().max(x0 + 1.0);
    let y1 = good.iter().fold(0.0f64, |a, p| a.max(p.error)) * 1.1;
    let y1 = if y1 > 0.0 { y1 } else { 1.0 };
    // Errors spanning more than a decade and a half go on a log axis, so good settings are
    // not squashed against zero by a poor one.
    let ymin = good
        .iter()
        .map(|p| p.error)
        .filter(|&e| e > 0.0)
        .fold(f64::INFINITY, f64::min);
    let log_y = ymin.is_finite() && y1 / ymin > 30.0;
    let (ly0, ly1) = if log_y {
        ((ymin / 1.5).log10().floor(), y1.log10().ceil())
    } else {
        (0.0, 1.0)
    };
    let sx = |s: f64| l + (s.log10() - x0) / (x1 - x0) * pw;
    let sy = |e: f64| {
        if log_y {
            let v = e.max(10f64.powf(ly0)).log10();
            t + ph - (v - ly0) / (ly1 - ly0) * ph
        } else {
            t + ph - e / y1 * ph
        }
    };
    let mut o = String::new();
    let _ = writeln!(
        o,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(o, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
    let _ = writeln!(
        o,
        r#"<text x="{}" y="28" font-size="16" text-anchor="middle">{}</text>"#,
        l + pw / 2.0,
        esc(title)
    );
    // Axes, decades on x, five steps on y.
    let _ = writeln!(
        o,
        r#"<rect x="{l}" y="{t}" width="{pw}" height="{ph}" fill="none" stroke="black"/>"#
    );
    x_ticks(&mut o, x0, x1, &sx, (t, t + ph));
    let ticks = y_ticks(log_y, (ly0, ly1), y1);
    for e in ticks {
        let y = sy(e);
        let _ = writeln!(
            o,
            r##"<line x1="{l}" y1="{y:.1}" x2="{}" y2="{y:.1}" stroke="#eee"/><text x="{}" y="{:.1}" text-anchor="end">{}</text>"##,
            l + pw,
            l - 6.0,
            y + 4.0,
            if e >= 0.01 || e == 0.0 {
                format!("{e:.3}")
            } else {
                format!("{e:.0e}")
            }
        );
    }
    let _ = writeln!(
        o,
        r#"<text x="{}" y="{}" text-anchor="middle">wall time (s, log scale)</text>"#,
        l + pw / 2.0,
        h - 15.0
    );
    let _ = writeln!(
        o,
        r#"<text x="20" y="{}" text-anchor="middle" transform="rotate(-90 20 {})">{}{}</text>"#,
        t + ph / 2.0,
        t + ph / 2.0,
        esc(y_name),
        if log_y { " (log scale)" } else { "" }
    );
    // Pareto front.
    let front = pareto_front(points);
    front_path(&mut o, points, &front, &sx, &sy);
    // Points and labels by series.
    let mut series: Vec<&str> = Vec::new();
    for p in &good {
        if !series.contains(&p.series.as_str()) {
            series.push(&p.series);
        }
    }
    for (i, p) in points.iter().enumerate() {
        if !(p.seconds.is_finite() && p.seconds > 0.0 && p.error.is_finite()) {
            continue;
        }
        let c = PALETTE[series.iter().position(|s| *s == p.series).unwrap_or(0) % PALETTE.len()];
        let (x, y) = (sx(p.seconds), sy(p.error));
        let ring = if front.contains(&i) {
            r#" stroke="black" stroke-width="1.5""#
        } else {
            ""
        };
        let _ = writeln!(
            o,
            r#"<circle cx="{x:.1}" cy="{y:.1}" r="4.5" fill="{c}"{ring}><title>{}: {} — {:.3} s, {:.4}</title></circle><text x="{:.1}" y="{:.1}" font-size="9" fill="{c}">{}</text>"#,
            esc(&p.series),
            esc(&p.label),
            p.seconds,
            p.error,
            x + 6.0,
            y - 4.0,
            esc(&p.label)
        );
    }
    // Legend.
    for (k, s) in series.iter().enumerate() {
        let y = t + 10.0 + 20.0 * k as f64;
        let _ = writeln!(
            o,
            r#"<circle cx="{}" cy="{y}" r="5" fill="{}"/><text x="{}" y="{}">{}</text>"#,
            l + pw + 20.0,
            PALETTE[k % PALETTE.len()],
            l + pw + 32.0,
            y + 4.0,
            esc(s)
        );
    }
    let y = t + 10.0 + 20.0 * series.len() as f64;
    let _ = writeln!(
        o,
        r##"<line x1="{}" y1="{y}" x2="{}" y2="{y}" stroke="#555" stroke-dasharray="5,4"/><text x="{}" y="{}">Pareto front (ringed)</text>"##,
        l + pw + 12.0,
        l + pw + 28.0,
        l + pw + 32.0,
        y + 4.0
    );
    o.push_str("</svg>\n");
    o
}

/// The Pareto front as a dashed staircase through `front` (indices into `points`).
fn front_path(
    o: &mut String,
    points: &[PlotPoint],
    front: &[usize],
    sx: &dyn Fn(f64) -> f64,
    sy: &dyn Fn(f64) -> f64,
) {
    if front.len() > 1 {
        let mut path = String::new();
        for (k, &i) in front.iter().enumerate() {
            let (x, y) = (sx(points[i].seconds), sy(points[i].error));
            if k == 0 {
                let _ = write!(path, "M{x:.1},{y:.1}");
            } else {
                let _ = write!(path, " H{x:.1} V{y:.1}");
            }
        }
        let _ = writeln!(
            o,
            r##"<path d="{path}" fill="none" stroke="#555" stroke-dasharray="5,4"/>"##
        );
    }
}

/// Decade and in-between ticks on the logarithmic x axis from `10^x0` to `10^x1` seconds, with
/// grid lines from the plot's `top` to its `bottom` and labels at the decades.
fn x_ticks(o: &mut String, x0: f64, x1: f64, sx: &dyn Fn(f64) -> f64, (top, bottom): (f64, f64)) {
    let mut d = x0;
    while d <= x1 + 1e-9 {
        for m in 1..10 {
            let s = 10f64.powf(d) * m as f64;
            if s.log10() > x1 + 1e-9 {
                break;
            }
            let x = sx(s);
            let (len, col) = if m == 1 { (6.0, "#bbb") } else { (3.0, "#eee") };
            let _ = writeln!(
                o,
                r#"<line x1="{x:.1}" y1="{top}" x2="{x:.1}" y2="{}" stroke="{col}"/><line x1="{x:.1}" y1="{}" x2="{x:.1}" y2="{}" stroke="black"/>"#,
                bottom,
                bottom,
                bottom + len
            );
            if m == 1 {
                let _ = writeln!(
                    o,
                    r#"<text x="{x:.1}" y="{}" text-anchor="middle">{}</text>"#,
                    bottom + 20.0,
                    fmt_seconds(s)
                );
            }
        }
        d += 1.0;
    }
}

/// The y values that get a tick: 1, 2, 5 per decade from `10^ly0` to `10^ly1` on a log axis,
/// else five steps to `y1`.
fn y_ticks(log_y: bool, (ly0, ly1): (f64, f64), y1: f64) -> Vec<f64> {
    if log_y {
        let mut v = Vec::new();
        let mut d = ly0;
        while d <= ly1 + 1e-9 {
            for m in [1.0, 2.0, 5.0] {
                let e = 10f64.powf(d) * m;
                if e.log10() <= ly1 + 1e-9 {
                    v.push(e);
                }
            }
            d += 1.0;
        }
        v
    } else {
        (0..=5).map(|k| y1 * k as f64 / 5.0).collect()
    }
}

fn fmt_seconds(s: f64) -> String {
    if s >= 1.0 {
        format!("{s:.0}")
    } else {
        let digits = (-s.log10()).ceil().max(0.0) as usize;
        format!("{s:.digits$}")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p(s: f64, e: f64) -> PlotPoint {
        PlotPoint {
            series: "a".into(),
            label: String::new(),
            seconds: s,
            error: e,
        }
    }

    #[test]
    fn pareto_front_keeps_only_undominated_points() {
        let pts = [
            p(1.0, 0.5),
            p(2.0, 0.3),
            p(3.0, 0.4),
            p(0.5, 0.9),
            p(4.0, 0.1),
        ];
        assert_eq!(pareto_front(&pts), vec![3, 0, 1, 4]);
        assert!(pareto_front(&[p(f64::NAN, 0.1)]).is_empty());
    }

    #[test]
    fn svg_has_every_point_and_no_nan() {
        let pts = [p(0.2, 0.05), p(3.0, 0.02), p(f64::NAN, 1.0)];
        let s = render_svg("t", "e_A", &pts);
        assert_eq!(s.matches("<circle cx").count(), 2 + 1); // 2 points + 1 legend entry
        assert!(!s.contains("NaN") && !s.contains("inf"));
        assert!(s.starts_with("<svg") && s.trim_end().ends_with("</svg>"));
    }
}
