//! The crate's one random source, counter-based: the stream for index `i` depends only on
//! (seed, i), so maps, noise and samples are identical whatever the thread count or order.
//!
//! Two generators share the SplitMix64 step: [`Rng`] (occlusion directions, sampling, tests)
//! and [`SplitMix64`] (the virtual scanner's range noise). Their seeding differs, and each
//! stream is pinned by a test: changing either changes every output that depends on it.

use std::f64::consts::TAU;

/// SplitMix64 step; also a well-spread hash of one word.
#[inline]
pub fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A small generator seeded from (seed, stream).
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    /// The generator for stream `stream` (e.g. a pixel index) under `seed`.
    #[inline]
    pub fn new(seed: u64, stream: u64) -> Rng {
        Rng(splitmix64(
            seed ^ splitmix64(stream.wrapping_add(0x5851_F42D_4C95_7F2D)),
        ))
    }

    /// Next 64 random bits.
    #[inline]
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        splitmix64(self.0)
    }

    /// Uniform in [0, 1).
    #[inline]
    pub fn next_f32(&mut self) -> f32 {
        (self.next_u64() >> 40) as f32 * (1.0 / (1u64 << 24) as f32)
    }
}

/// SplitMix64 seeded from (seed, index), with doubles and normal deviates: the virtual
/// scanner's range noise.
#[derive(Debug, Clone)]
pub struct SplitMix64(u64);

impl SplitMix64 {
    /// Generator for stream `index` of `seed`.
    pub fn new(seed: u64, index: u64) -> Self {
        let mut s = SplitMix64(index);
        let h = s.next_u64();
        SplitMix64(seed ^ h)
    }

    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        // The state advances before the mix, so this is `splitmix64` of the previous state.
        let z = splitmix64(self.0);
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z
    }

    /// Uniform in the open interval (0, 1).
    pub fn next_f64(&mut self) -> f64 {
        ((self.next_u64() >> 11) as f64 + 0.5) * (1.0 / (1u64 << 53) as f64)
    }

    /// Standard normal deviate (Box–Muller).
    pub fn gaussian(&mut self) -> f64 {
        let (u1, u2) = (self.next_f64(), self.next_f64());
        (-2.0 * u1.ln()).sqrt() * (TAU * u2).cos()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Literal values of each stream: every seeded output (occlusion maps, synthetic scans,
    /// reference samples) depends on them staying exactly these.
    #[test]
    fn streams_are_pinned() {
        assert_eq!(splitmix64(0), 0xe220_a839_7b1d_cdaf);
        assert_eq!(splitmix64(1), 0x910a_2dec_8902_5cc1);
        let mut r = Rng::new(7, 3);
        let u: Vec<u64> = (0..3).map(|_| r.next_u64()).collect();
        assert_eq!(
            u,
            [
                0xdefc_300a_bb37_2b03,
                0x11f6_7c2e_27f2_c84a,
                0x3d12_637c_05ba_6b6b
            ]
        );
        let mut r = Rng::new(1, 12345);
        let f: Vec<u32> = (0..3).map(|_| r.next_f32().to_bits()).collect();
        assert_eq!(f, [0x3f30_2bc7, 0x3ed1_10cc, 0x3ea0_6d26]);
        let mut s = SplitMix64::new(5, 0);
        let u: Vec<u64> = (0..3).map(|_| s.next_u64()).collect();
        assert_eq!(
            u,
            [
                0x3eb2_ecbc_9039_07fc,
                0xaca8_dc86_fd9b_769a,
                0x724d_fa47_5b89_e19f
            ]
        );
        let mut s = SplitMix64::new(0x5EED_4E61, 9);
        let g: Vec<u64> = (0..3).map(|_| s.gaussian().to_bits()).collect();
        assert_eq!(
            g,
            [
                0x3fd7_97b2_e190_63d6,
                0xbfee_1198_7e24_f2ee,
                0x3ff6_f832_7c79_f2b9
            ]
        );
        assert_eq!(
            SplitMix64::new(42, 7).next_f64().to_bits(),
            0x3fdb_aae1_8977_c9a3
        );
    }

    #[test]
    fn streams_are_reproducible_and_uniform() {
        let mut a = Rng::new(7, 3);
        let mut b = Rng::new(7, 3);
        let xs: Vec<f32> = (0..10_000).map(|_| a.next_f32()).collect();
        assert!(xs
            .iter()
            .zip((0..10_000).map(|_| b.next_f32()))
            .all(|(x, y)| *x == y));
        assert!(xs.iter().all(|&x| (0.0..1.0).contains(&x)));
        let mean = xs.iter().sum::<f32>() / xs.len() as f32;
        assert!((mean - 0.5).abs() < 0.01);
        assert_ne!(Rng::new(7, 4).next_u64(), Rng::new(7, 3).next_u64());
    }

    #[test]
    fn splitmix_gaussian_moments() {
        let mut r = SplitMix64::new(5, 0);
        let v: Vec<f64> = (0..200_000).map(|_| r.gaussian()).collect();
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / v.len() as f64;
        assert!(
            mean.abs() < 0.01 && (var - 1.0).abs() < 0.02,
            "{mean} {var}"
        );
    }
}
