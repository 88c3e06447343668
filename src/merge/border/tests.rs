use super::*;

/// SplitMix64: small deterministic PRNG for the tests.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
}

fn random_seeds(rng: &mut Rng, n: usize, density: f64) -> Vec<bool> {
    (0..n).map(|_| rng.unit() < density).collect()
}

fn mismatches(a: &[f32], b: &[f32]) -> usize {
    assert_eq!(a.len(), b.len());
    a.iter()
        .zip(b)
        .filter(|(x, y)| !(x == y || (*x - *y).abs() <= 1e-4))
        .count()
}

const SIZES: [(usize, usize); 8] = [
    (1, 1),
    (1, 50),
    (50, 1),
    (2, 2),
    (37, 23),
    (23, 37),
    (64, 64),
    (200, 100),
];
const DENSITIES: [f64; 4] = [0.001, 0.01, 0.1, 0.5];

#[test]
fn distance_field_equals_brute_force_on_random_images() {
    let mut rng = Rng(12345);
    let mut cases = 0;
    for &(w, h) in &SIZES {
        for &density in &DENSITIES {
            for wrap in [false, true] {
                let reps = if w * h >= 4096 { 4 } else { 12 };
                for _ in 0..reps {
                    let seeds = random_seeds(&mut rng, w * h, density);
                    let field = distance_field(&seeds, w, h, wrap);
                    let exact = brute_force_distance(&seeds, w, h, wrap);
                    let bad = mismatches(&field, &exact);
                    assert_eq!(bad, 0, "{w}x{h} density {density} wrap {wrap}");
                    cases += 1;
                }
            }
        }
    }
    assert!(cases > 300);
}

#[test]
fn distance_field_single_seeds_and_wrap() {
    // A single seed anywhere: the longest distances.
    for (w, h) in [(13, 7), (64, 3), (5, 40), (100, 100)] {
        for wrap in [false, true] {
            for i in [0, w * h / 2 + 1, w * h - 1, w - 1, (h - 1) * w] {
                let mut seeds = vec![false; w * h];
                seeds[i] = true;
                let field = distance_field(&seeds, w, h, wrap);
                let exact = brute_force_distance(&seeds, w, h, wrap);
                assert_eq!(
                    mismatches(&field, &exact),
                    0,
                    "{w}x{h} seed {i} wrap {wrap}"
                );
            }
        }
    }
    // Wrapping distance goes across the seam.
    let mut seeds = vec![false; 10];
    seeds[0] = true;
    let d = distance_field(&seeds, 10, 1, true);
    assert_eq!(d, vec![0.0, 1.0, 2.0, 3.0, 4.0, 5.0, 4.0, 3.0, 2.0, 1.0]);
    let d = distance_field(&seeds, 10, 1, false);
    assert_eq!(d[9], 9.0);
    let mut seeds = vec![false; 12];
    seeds[0] = true; // (0, 0) in a 4 × 3 image
    let d = distance_field(&seeds, 4, 3, false);
    assert_eq!(d[11], 13f32.sqrt()); // (3, 2)
}

#[test]
fn distance_field_degenerate_inputs() {
    assert!(distance_field(&[], 0, 5, false).is_empty());
    assert!(distance_field(&[], 5, 0, true).is_empty());
    assert!(brute_force_distance(&[], 0, 0, false).is_empty());
    let d = distance_field(&[false; 6], 3, 2, false);
    assert!(d.iter().all(|v| *v == f32::INFINITY));
    assert_eq!(distance_field(&[true], 1, 1, true), vec![0.0]);
    assert_eq!(distance_field(&[false], 1, 1, false), vec![f32::INFINITY]);
    // Too short a mask is padded with non-seeds.
    assert_eq!(distance_field(&[true], 3, 1, false), vec![0.0, 1.0, 2.0]);
}

const INF: f32 = f32::INFINITY;

#[test]
fn laplacian_hand_computed_3x3() {
    #[rustfmt::skip]
        let d = [
            1.0, 2.0, 3.0,
            4.0, 5.0, 6.0,
            7.0, 8.0, 9.0,
        ];
    // D_far = 18. Centre: (2-5)+(4-5)+(6-5)+(8-5) = 0.
    // (0,0): (2-1)+(4-1)+2·(18-1) = 38, / 1.  (1,0): (1-2)+(3-2)+(5-2)+(18-2) = 19, / 2.
    // (2,2): (6-9)+(8-9)+2·(18-9) = 14, / 9.
    let l = laplacian(&d, 3, 3, false);
    assert_eq!(l[4], 0.0);
    assert_eq!(l[0], 38.0);
    assert_eq!(l[1], 9.5);
    assert!((l[8] - 14.0 / 9.0).abs() < 1e-6);
    // Wrap: (0,0)'s left neighbour is (2,0) = 3: 1 + 3 + 2 + 17 = 23.
    // (2,0)'s right neighbour is (0,0) = 1: (2-3)+(1-3)+(6-3)+(18-3) = 15, / 3 = 5.
    let l = laplacian(&d, 3, 3, true);
    assert_eq!(l[0], 23.0);
    assert_eq!(l[2], 5.0);
    assert_eq!(l[4], 0.0);
    // (1,1) is unchanged by wrap; (0,1): (6-4)+(5-4)+(1-4)+(7-4) = 3, / 4.
    assert_eq!(l[3], 0.75);
}

#[test]
fn laplacian_empty_neighbour() {
    #[rustfmt::skip]
        let d = [
            1.0, 2.0, 3.0,
            4.0, 5.0, INF,
            7.0, 8.0, 9.0,
        ];
    let l = laplacian(&d, 3, 3, false);
    // D_far = 18 still. Centre: (2-5)+(4-5)+(18-5)+(8-5) = 12, / 5.
    assert_eq!(l[4], 2.4);
    assert_eq!(l[5], 0.0);
    // (2,0): (2-3)+2·(18-3) (right, up outside) + (18-3) (down empty) = 44, / 3.
    assert!((l[2] - 44.0 / 3.0).abs() < 1e-6);
}

#[test]
fn laplacian_4x4_wrap_and_guards() {
    // A constant ring around the panorama: with wrap the rows have no side borders.
    let mut d = vec![2.0f32; 16];
    let l = laplacian(&d, 4, 4, true);
    // Rows 1 and 2 are flat; rows 0 and 3 see the background (D_far = 4) above/below.
    assert_eq!(&l[4..12], &[0.0; 8]);
    assert_eq!(&l[0..4], &[1.0; 4]); // (4-2)/2
    let l = laplacian(&d, 4, 4, false);
    assert_eq!(l[5], 0.0);
    assert_eq!(l[4], 1.0);
    assert_eq!(l[0], 2.0);
    // Zero depth uses 1e-6 as denominator; no NaN anywhere.
    d[5] = 0.0;
    d[6] = f32::NAN;
    d[10] = f32::NEG_INFINITY;
    let l = laplacian(&d, 4, 4, false);
    assert!(l.iter().all(|v| !v.is_nan()));
    assert_eq!(l[6], 0.0);
    assert_eq!(l[10], 0.0);
    // (1,1) = 0: neighbours 2 (left, up, below) and 4 (empty right): 10 / 1e-6.
    assert!((l[5] / 1e7 - 1.0).abs() < 1e-6);
    // All empty → all zero.
    assert_eq!(laplacian(&[INF; 4], 2, 2, true), vec![0.0; 4]);
    assert!(laplacian(&[], 0, 3, false).is_empty());
}

#[test]
fn nth_valid_equals_a_sort() {
    let mut rng = crate::ssao::rng::Rng::new(11, 0);
    let mut next = || rng.next_u64();
    for n in [1usize, 2, 5, 300, 70_000, 200_003] {
        for round in 0..3 {
            let lap: Vec<f32> = (0..n)
                .map(|_| match (next() % 16, round) {
                    (0, _) => -0.0,
                    (1, _) => 0.0,
                    (2, _) => f32::INFINITY,
                    (3, 2) => -1.5,
                    // Few distinct values on round 1: ties.
                    (_, 1) => (next() % 5) as f32 * 0.25,
                    _ => f32::from_bits(next() as u32 & 0x7f7f_ffff),
                })
                .collect();
            let depth: Vec<f32> = (0..n).map(|i| if i % 7 == 3 { INF } else { 1.0 }).collect();
            let mut valid: Vec<f32> = lap
                .iter()
                .zip(&depth)
                .filter(|(_, d)| d.is_finite())
                .map(|(l, _)| *l)
                .collect();
            valid.sort_by(f32::total_cmp);
            for k in [0, valid.len() / 2, valid.len() * 95 / 100, valid.len() - 1] {
                let got = nth_valid(&lap, &depth, k);
                assert_eq!(
                    got.to_bits(),
                    valid[k].to_bits(),
                    "n {n} round {round} k {k}"
                );
            }
        }
    }
}

#[test]
fn edge_mask_quantile_nearest_rank() {
    // Values 1..=100 in a shuffled order, plus empty pixels with huge Laplacian (ignored).
    let mut lap: Vec<f32> = (1..=100).map(|v| ((v * 37) % 100 + 1) as f32).collect();
    let mut depth = vec![1.0f32; 100];
    lap.push(1e9);
    depth.push(INF);
    let m = edge_mask(&lap, &depth, 0.95);
    // Nearest rank: τ = 95th smallest = 95, so 95..=100 are edges.
    assert_eq!(m.iter().filter(|e| **e).count(), 6);
    for (l, e) in lap.iter().zip(&m).take(100) {
        assert_eq!(*e, *l >= 95.0);
    }
    assert!(!m[100]);
    let m = edge_mask(&lap, &depth, 0.951);
    assert_eq!(m.iter().filter(|e| **e).count(), 5);
    assert_eq!(
        edge_mask(&lap, &depth, 1.0).iter().filter(|e| **e).count(),
        1
    );
    assert_eq!(
        edge_mask(&lap, &depth, 0.0).iter().filter(|e| **e).count(),
        100
    );
}

#[test]
fn flat_and_empty_maps_have_no_edges() {
    let lap = vec![0.0f32; 50];
    let depth = vec![3.0f32; 50];
    assert!(edge_mask(&lap, &depth, 0.95).iter().all(|e| !e));
    assert!(edge_mask(&[5.0; 4], &[INF; 4], 0.95).iter().all(|e| !e));
    assert!(edge_mask(&[], &[], 0.95).is_empty());
    // An all-empty map has no edges, hence infinite distances.
    let d = border_distance(&[INF; 12], 4, 3, true);
    assert!(d.iter().all(|v| *v == INF));
}

#[test]
fn depth_step_gives_edges_along_the_step() {
    // 64 × 64, depth 1 for x < 32 and 100 for x ≥ 32, D_far = 200.
    // L: x=31 interior 99, x=32 interior 0.99, left column 199, right column 1,
    // top/bottom rows ≥ 199 on the left half, 1 on the right half except x=32 (0.01),
    // corners 398 / 2, interior 0. 188 values ≥ 99, then 2 corners at 2: the 205 largest
    // values (nearest rank 3892 of 4096) end inside the 1s, so τ = 1.
    let (w, h) = (64usize, 64usize);
    let depth: Vec<f32> = (0..w * h)
        .map(|i| if i % w < 32 { 1.0 } else { 100.0 })
        .collect();
    let lap = laplacian(&depth, w, h, false);
    assert!((lap[10 * w + 31] - 99.0).abs() < 1e-4);
    assert!((lap[10 * w + 32] - 0.99).abs() < 1e-6);
    let edges = edge_mask(&lap, &depth, 0.95);
    for y in 0..h {
        for x in 0..w {
            let want = x == 0 || x == 31 || x == 63 || ((y == 0 || y == 63) && x != 32);
            assert_eq!(edges[y * w + x], want, "({x}, {y})");
        }
    }
    let dist = border_distance(&depth, w, h, false);
    for y in 0..h {
        for x in 0..w {
            let want = if x == 32 && (y == 0 || y == 63) {
                1.0 // the gap in the top/bottom edge rows is next to column 31
            } else {
                x.min(x.abs_diff(31)).min(63 - x).min(y).min(63 - y) as f32
            };
            assert_eq!(dist[y * w + x], want, "({x}, {y})");
        }
    }
}

#[test]
fn distance_field_equals_brute_force_on_random_sizes() {
    // Odd and tiny widths, single rows and columns, sparse seeds: the envelope's edge cases.
    let mut rng = Rng(777);
    for i in 0..3000 {
        let w = 1 + (rng.next() % 40) as usize;
        let h = 1 + (rng.next() % 40) as usize;
        let density = [0.0005, 0.002, 0.01, 0.05, 0.3][i % 5];
        let seeds = random_seeds(&mut rng, w * h, density);
        let wrap = i % 2 == 0;
        let field = distance_field(&seeds, w, h, wrap);
        let exact = brute_force_distance(&seeds, w, h, wrap);
        assert_eq!(mismatches(&field, &exact), 0, "{w}x{h} wrap {wrap}");
    }
}
