//! LAS and LAZ speeds on five million scan-like points: `cargo bench --bench las`.
//!
//! A generated LAS 1.4 format 6 file with one extra dimension is read (`LasInput::from_path`), turned
//! into a scan (`raw_scan`) and written back with AO, uncompressed and as LAZ, each step timed
//! once.

#[path = "../tests/common/las_gen.rs"]
mod las_gen;

use las_gen::{ao_values, dim, make_las_from, Spec};
use mvao::io::las::{write_las, LasInput};
use mvao::io::output::ColorMode;
use rayon::prelude::*;

fn main() {
    let dir = tempfile::tempdir().expect("temporary directory");
    let mut spec = Spec::new((1, 4), 6);
    spec.n = 5_000_000;
    spec.dims = vec![dim("reflectance", 9)];
    let inp = dir.path().join("big.las");
    // A scan-like sweep: neighbouring points close in space, time, intensity and colour,
    // as the LAZ coder expects (random bytes would be its worst case).
    let len = 34;
    let mut recs = vec![0u8; spec.n * len];
    recs.par_chunks_exact_mut(len)
        .enumerate()
        .for_each(|(k, r)| {
            let (row, col) = ((k / 2000) as f64, (k % 2000) as f64);
            let x = (col * 5.0) as i32;
            let y = (row * 5.0) as i32;
            let z = (1000.0 * (col * 0.01).sin() * (row * 0.02).cos()) as i32;
            r[0..4].copy_from_slice(&x.to_le_bytes());
            r[4..8].copy_from_slice(&y.to_le_bytes());
            r[8..12].copy_from_slice(&z.to_le_bytes());
            r[12..14].copy_from_slice(&((20000 + z * 10) as u16).to_le_bytes());
            r[14] = 0x09;
            r[16] = 2;
            r[20..22].copy_from_slice(&1u16.to_le_bytes());
            r[22..30].copy_from_slice(&(1.0e8 + k as f64 * 1e-5).to_le_bytes());
            r[30..34].copy_from_slice(&(0.5f32 + z as f32 * 1e-4).to_le_bytes());
        });
    let t = std::time::Instant::now();
    make_las_from(&inp, &spec, recs);
    println!("generate {} points: {:?}", spec.n, t.elapsed());
    let t = std::time::Instant::now();
    let input = LasInput::from_path(&inp).expect("bench I/O");
    println!("LasInput::from_path LAS: {:?}", t.elapsed());
    let t = std::time::Instant::now();
    let scan = input.raw_scan("big");
    println!("raw_scan: {:?} ({} points)", t.elapsed(), scan.xyz.len());
    let ao = ao_values(spec.n);
    for compress in [false, true] {
        let out = dir.path().join(if compress {
            "big.out.laz"
        } else {
            "big.out.las"
        });
        let t = std::time::Instant::now();
        write_las(&input, &ao, &[], 1.0, ColorMode::Modulate, &out, compress).expect("bench I/O");
        println!(
            "write_las compress={compress}: {:?}, {} bytes",
            t.elapsed(),
            std::fs::metadata(&out).expect("bench I/O").len()
        );
        let t = std::time::Instant::now();
        let back = LasInput::from_path(&out).expect("bench I/O");
        println!("LasInput::from_path compress={compress}: {:?}", t.elapsed());
        assert_eq!(back.len(), spec.n);
    }
}
