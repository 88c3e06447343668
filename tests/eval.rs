//! Error metrics on hand-computed vectors.

use mvao::testing::eval::{metrics, metrics_concat, Metrics};

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < 1e-6
}

#[test]
fn hand_computed_metrics() {
    // a − A = [0.1, −0.02, 0.0, −0.3]; |d| = [0.1, 0.02, 0, 0.3].
    let reference = [0.5f32, 1.0, 0.8, 0.95];
    let a = [0.6f32, 0.98, 0.8, 0.65];
    let m = metrics(&a, &reference);
    assert_eq!(m.n, 4);
    assert_eq!(m.skipped, 0);
    assert!(close(m.e_a, 0.42 / 4.0), "{}", m.e_a);
    // |d| < 0.05: 0.02 and 0.
    assert!(close(m.e_lt5, 0.5));
    // RMSE = sqrt((0.01 + 0.0004 + 0 + 0.09)/4).
    assert!(close(m.rmse, (0.1004f64 / 4.0).sqrt()));
    assert!(close(m.bias, (0.1 - 0.02 - 0.3) / 4.0));
    // Shaded (A < 0.9): 0.5 and 0.8 → |d| 0.1 and 0.
    assert_eq!(m.shaded_n, 2);
    assert!(close(m.shaded_e_a.unwrap(), 0.05));
    // Baseline a = 1: |1 − A| = [0.5, 0, 0.2, 0.05].
    assert!(close(m.baseline_e_a, 0.75 / 4.0));
    assert!(close(m.baseline_shaded_e_a.unwrap(), 0.35));
    assert!(close(m.skill.unwrap(), 1.0 - 0.105 / 0.1875));
    assert!(close(m.shaded_skill.unwrap(), 1.0 - 0.05 / 0.35));
    // Pearson r by hand: means a 0.7575, A 0.8125.
    let (ma, mr) = (0.7575f64, 0.8125f64);
    let (mut c, mut va, mut vr) = (0.0, 0.0, 0.0);
    for (x, y) in a.iter().zip(&reference) {
        let (x, y) = (*x as f64 - ma, *y as f64 - mr);
        c += x * y;
        va += x * x;
        vr += y * y;
    }
    assert!((m.pearson_r.unwrap() - c / (va * vr).sqrt()).abs() < 1e-5);
    let line = m.one_line();
    assert!(
        line.contains("n=4") && line.contains("e_A=0.1050") && line.contains("e<5%=50.0%"),
        "{line}"
    );
}

#[test]
fn perfect_and_constant_inputs_give_no_nan() {
    let r = [0.2f32, 0.5, 0.9, 1.0];
    let m = metrics(&r, &r);
    assert_eq!((m.e_a, m.rmse, m.bias, m.e_lt5), (0.0, 0.0, 0.0, 1.0));
    assert!(close(m.pearson_r.unwrap(), 1.0));
    assert_eq!(m.skill, Some(1.0));
    // Constant estimate: zero variance → no correlation, no NaN anywhere.
    let m = metrics(&[1.0; 4], &r);
    assert_eq!(m.pearson_r, None);
    assert_eq!(m.skill, Some(0.0));
    let json = serde_json::to_string(&m).unwrap();
    assert!(
        !json.contains("NaN") && json.contains("\"pearson_r\":null"),
        "{json}"
    );
    // All open reference: the baseline is exact, skill undefined.
    let m = metrics(&[0.9; 3], &[1.0; 3]);
    assert_eq!(m.baseline_e_a, 0.0);
    assert_eq!((m.skill, m.shaded_e_a, m.shaded_skill), (None, None, None));
    assert_eq!(m.shaded_n, 0);
    assert!(close(m.bias, -0.1));
    // Nothing to compare.
    let m = metrics(&[], &[]);
    assert_eq!(m, Metrics::default());
    assert!(m.one_line().contains("n=0"));
}

#[test]
fn nonfinite_and_mismatched_values_are_skipped() {
    let m = metrics(&[f32::NAN, 0.5, 0.7, 0.1], &[0.5, f32::INFINITY, 0.7]);
    assert_eq!(m.n, 1);
    assert_eq!(m.skipped, 3);
    assert_eq!(m.e_a, 0.0);
}

#[test]
fn merge_uses_the_concatenated_values() {
    let (a1, r1) = ([0.5f32, 0.5], [0.5f32, 0.7]);
    let (a2, r2) = ([0.0f32], [1.0f32]);
    let all = metrics_concat(&[(&a1, &r1), (&a2, &r2)]);
    let flat = metrics(&[0.5, 0.5, 0.0], &[0.5, 0.7, 1.0]);
    assert_eq!(all, flat);
    // e_A = (0 + 0.2 + 1)/3, not the mean of the per-scan 0.1 and 1.0.
    assert!(close(all.e_a, 0.4));
    assert_eq!(all.n, 3);
}
