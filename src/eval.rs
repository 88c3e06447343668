//! Error metrics of an AO estimate `a` against the reference obscurance `A` (Timonen 2013):
//! `e_A` = mean |a − A|, `e_<5%` = share of points with |a − A| < 0.05, RMSE, Pearson r, bias,
//! the same on the shaded points (`A < 0.9`), and the baseline of answering "open" everywhere
//! (`a = 1`) with the skill over it.
//!
//! Pairs where either value is not finite are left out and counted; metrics of several scans
//! together come from the concatenated values ([`metrics_concat`]), never from averaging
//! per-scan metrics. Undefined quantities (no point, zero variance, zero baseline) are `None`
//! (JSON `null`), never NaN.

use serde::Serialize;

/// Reference values below this are "shaded".
pub const SHADED_BELOW: f32 = 0.9;
/// `e_<5%` counts errors below this.
pub const CLOSE: f32 = 0.05;

/// Error metrics of one estimate against the reference.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Default)]
pub struct Metrics {
    /// Pairs compared.
    pub n: usize,
    /// Pairs left out: a non-finite value, or past the end of the shorter input.
    pub skipped: usize,
    /// Mean |a − A|.
    pub e_a: f64,
    /// Share of points with |a − A| < 0.05.
    pub e_lt5: f64,
    /// sqrt(mean (a − A)²).
    pub rmse: f64,
    /// Pearson correlation of a and A; `None` when either is constant or there is no point.
    pub pearson_r: Option<f64>,
    /// Mean a − A (positive: the estimate is too bright).
    pub bias: f64,
    /// Points with A < 0.9.
    pub shaded_n: usize,
    /// Mean |a − A| over the shaded points.
    pub shaded_e_a: Option<f64>,
    /// Mean |1 − A|: the error of answering "open" everywhere.
    pub baseline_e_a: f64,
    /// Mean |1 − A| over the shaded points.
    pub baseline_shaded_e_a: Option<f64>,
    /// 1 − e_A / baseline e_A: 1 = exact, 0 = no better than white, negative = worse.
    pub skill: Option<f64>,
    /// The same on the shaded points.
    pub shaded_skill: Option<f64>,
}

/// Metrics of `a` against `reference` (same order, same length; extra values of the longer
/// slice are counted as skipped).
pub fn metrics(a: &[f32], reference: &[f32]) -> Metrics {
    metrics_concat(&[(a, reference)])
}

/// Metrics of several (estimate, reference) pairs of slices taken as one concatenated set:
/// the overall figure of several scans.
pub fn metrics_concat(parts: &[(&[f32], &[f32])]) -> Metrics {
    let pairs = || {
        parts.iter().flat_map(|(a, r)| {
            a.iter()
                .zip(r.iter())
                .map(|(&x, &y)| (x as f64, y as f64))
                .filter(|(x, y)| x.is_finite() && y.is_finite())
        })
    };
    let total: usize = parts.iter().map(|(a, r)| a.len().max(r.len())).sum();
    let mut m = Metrics::default();
    let (mut sa, mut sr, mut sd, mut sd2, mut sad) = (0.0, 0.0, 0.0, 0.0, 0.0);
    let (mut close, mut sh_sad, mut base, mut sh_base) = (0usize, 0.0, 0.0, 0.0);
    for (x, y) in pairs() {
        let d = x - y;
        m.n += 1;
        sa += x;
        sr += y;
        sd += d;
        sd2 += d * d;
        sad += d.abs();
        base += (1.0 - y).abs();
        if d.abs() < CLOSE as f64 {
            close += 1;
        }
        if y < SHADED_BELOW as f64 {
            m.shaded_n += 1;
            sh_sad += d.abs();
            sh_base += (1.0 - y).abs();
        }
    }
    m.skipped = total - m.n;
    if m.n == 0 {
        return m;
    }
    let n = m.n as f64;
    m.e_a = sad / n;
    m.e_lt5 = close as f64 / n;
    m.rmse = (sd2 / n).sqrt();
    m.bias = sd / n;
    m.baseline_e_a = base / n;
    m.skill = skill(m.e_a, m.baseline_e_a);
    if m.shaded_n > 0 {
        let k = m.shaded_n as f64;
        m.shaded_e_a = Some(sh_sad / k);
        m.baseline_shaded_e_a = Some(sh_base / k);
        m.shaded_skill = skill(sh_sad / k, sh_base / k);
    }
    let (ma, mr) = (sa / n, sr / n);
    let (mut cov, mut va, mut vr) = (0.0, 0.0, 0.0);
    for (x, y) in pairs() {
        cov += (x - ma) * (y - mr);
        va += (x - ma) * (x - ma);
        vr += (y - mr) * (y - mr);
    }
    let den = (va * vr).sqrt();
    if den > 0.0 && den.is_finite() {
        m.pearson_r = Some((cov / den).clamp(-1.0, 1.0));
    }
    m
}

fn skill(e: f64, base: f64) -> Option<f64> {
    (base > 0.0).then(|| 1.0 - e / base)
}

fn opt(x: Option<f64>, digits: usize) -> String {
    x.map_or("-".into(), |v| format!("{v:.digits$}"))
}

impl Metrics {
    /// A one-line summary, e.g.
    /// `n=1000 e_A=0.0310 e<5%=87.2% rmse=0.0450 r=0.912 bias=+0.0040 | shaded n=200 e_A=0.0800 | white e_A=0.0900 skill=0.656`.
    pub fn one_line(&self) -> String {
        format!(
            "n={} e_A={:.4} e<5%={:.1}% rmse={:.4} r={} bias={:+.4} | shaded n={} e_A={} | white e_A={:.4} skill={}",
            self.n,
            self.e_a,
            100.0 * self.e_lt5,
            self.rmse,
            opt(self.pearson_r, 3),
            self.bias,
            self.shaded_n,
            opt(self.shaded_e_a, 4),
            self.baseline_e_a,
            opt(self.skill, 3),
        )
    }
}
