//! Generated LAS files for the LAS/LAZ tests and the LAS bench: every point format and
//! version, extra-bytes dimensions, deterministic record bytes.
#![allow(dead_code)]

use las::point::Format;
use las::{Builder, PointDataBuilder, Reader, Transform, Vector, Vlr, Writer};
use std::path::Path;

pub(crate) const STD_LEN: [usize; 11] = [20, 28, 26, 34, 57, 63, 30, 36, 38, 59, 67];
pub(crate) const WKT: &str = "PROJCS[\"ETRS89 / UTM zone 32N\",AUTHORITY[\"EPSG\",\"25832\"]]";

/// A small deterministic generator.
pub(crate) struct Lcg(pub(crate) u64);

impl Lcg {
    pub(crate) fn next(&mut self) -> u64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        self.0 >> 11
    }
    pub(crate) fn below(&mut self, n: u64) -> u64 {
        self.next() % n
    }
    pub(crate) fn byte(&mut self) -> u8 {
        self.next() as u8
    }
}

/// One extra-bytes dimension of a generated file: name and LAS data type (0 = undocumented
/// bytes, with their count).
#[derive(Clone)]
pub(crate) struct Dim {
    pub(crate) name: &'static str,
    pub(crate) data_type: u8,
    pub(crate) bytes: usize,
}

pub(crate) fn dim(name: &'static str, data_type: u8) -> Dim {
    let bytes = [0, 1, 1, 2, 2, 4, 4, 8, 8, 4, 8][data_type as usize];
    Dim {
        name,
        data_type,
        bytes,
    }
}

pub(crate) fn descriptor(d: &Dim) -> Vec<u8> {
    let mut b = vec![0u8; 192];
    b[2] = d.data_type;
    if d.data_type == 0 {
        b[3] = d.bytes as u8;
    }
    b[4..4 + d.name.len()].copy_from_slice(d.name.as_bytes());
    b
}

/// What a generated input looks like.
#[derive(Clone)]
pub(crate) struct Spec {
    pub(crate) version: (u8, u8),
    pub(crate) format: u8,
    /// Described extra dimensions.
    pub(crate) dims: Vec<Dim>,
    /// Extra bytes after the described ones, with no description.
    pub(crate) undocumented: usize,
    /// Two EVLRs (LAS 1.4 only).
    pub(crate) evlrs: bool,
    pub(crate) compress: bool,
    pub(crate) n: usize,
    pub(crate) seed: u64,
}

impl Spec {
    pub(crate) fn new(version: (u8, u8), format: u8) -> Spec {
        Spec {
            version,
            format,
            dims: Vec::new(),
            undocumented: 0,
            evlrs: false,
            compress: false,
            n: 257,
            seed: 7,
        }
    }
    pub(crate) fn extra_len(&self) -> usize {
        self.dims.iter().map(|d| d.bytes).sum::<usize>() + self.undocumented
    }
}

/// Random records of `spec`'s format, with return numbers the header counts can hold.
pub(crate) fn records(spec: &Spec) -> Vec<u8> {
    let len = STD_LEN[spec.format as usize] + spec.extra_len();
    let extended = spec.format >= 6;
    let mut rng = Lcg(spec.seed);
    let mut out = vec![0u8; spec.n * len];
    for r in out.chunks_exact_mut(len) {
        for b in r.iter_mut() {
            *b = rng.byte();
        }
        for a in 0..3 {
            let v = rng.below(2_000_000) as i32 - 1_000_000;
            r[4 * a..4 * a + 4].copy_from_slice(&v.to_le_bytes());
        }
        let gps_at = if extended { 22 } else { 20 };
        if extended || [1, 3, 4, 5].contains(&spec.format) {
            let t = 1.0e8 + rng.below(1_000_000_000) as f64 * 1e-3;
            r[gps_at..gps_at + 8].copy_from_slice(&t.to_le_bytes());
        }
        if extended {
            r[14] = (1 + rng.below(15)) as u8 | ((1 + rng.below(15)) as u8) << 4;
        } else {
            r[14] = (r[14] & 0xc0) | (1 + rng.below(5)) as u8 | ((1 + rng.below(5)) as u8) << 3;
        }
        // Waveform packets: plausible offsets and sizes, as the LAZ coder assumes.
        let wave_at = match spec.format {
            4 => Some(28),
            5 => Some(34),
            9 => Some(30),
            10 => Some(38),
            _ => None,
        };
        if let Some(w) = wave_at {
            r[w] = 1 + rng.below(3) as u8;
            r[w + 1..w + 9].copy_from_slice(&(rng.below(1 << 30)).to_le_bytes());
            r[w + 9..w + 13].copy_from_slice(&(rng.below(1 << 12) as u32).to_le_bytes());
            for c in 0..4 {
                let v = rng.below(10_000) as f32 * 1e-3;
                r[w + 13 + 4 * c..w + 17 + 4 * c].copy_from_slice(&v.to_le_bytes());
            }
        }
        // Float extra dims get real numbers (random bits can be NaN, which is legal but
        // makes the readers' printouts noisy).
        let mut at = STD_LEN[spec.format as usize];
        for d in &spec.dims {
            match d.data_type {
                9 => r[at..at + 4].copy_from_slice(&(rng.below(1000) as f32 * 0.01).to_le_bytes()),
                10 => r[at..at + 8].copy_from_slice(&(rng.below(1000) as f64 * 0.01).to_le_bytes()),
                _ => {}
            }
            at += d.bytes;
        }
    }
    out
}

pub(crate) fn transforms() -> Vector<Transform> {
    let t = |offset| Transform {
        scale: 0.001,
        offset,
    };
    Vector {
        x: t(512000.0),
        y: t(5200000.0),
        z: t(300.0),
    }
}

/// Writes `spec` as a LAS/LAZ file at `path` with the `las` crate; returns its records.
pub(crate) fn make_las(path: &Path, spec: &Spec) -> Vec<u8> {
    make_las_from(path, spec, records(spec))
}

/// Writes `recs` (of `spec`'s layout) as a LAS/LAZ file at `path`.
pub(crate) fn make_las_from(path: &Path, spec: &Spec, recs: Vec<u8>) -> Vec<u8> {
    let mut b = Builder::from(spec.version);
    let mut format = Format::new(spec.format).unwrap();
    format.extra_bytes = spec.extra_len() as u16;
    format.is_compressed = spec.compress;
    b.point_format = format;
    b.transforms = transforms();
    b.system_identifier = "HERITAGE TLS".into();
    b.generating_software = "survey suite 3".into();
    b.vlrs.push(Vlr {
        user_id: "LASF_Projection".into(),
        record_id: 2112,
        description: "OGC WKT".into(),
        data: WKT.as_bytes().to_vec(),
    });
    if !spec.dims.is_empty() {
        b.vlrs.push(Vlr {
            user_id: "LASF_Spec".into(),
            record_id: 4,
            description: "extra bytes".into(),
            data: spec.dims.iter().flat_map(descriptor).collect(),
        });
    }
    if spec.evlrs {
        for (k, size) in [(1u16, 100usize), (2, 70_000)] {
            b.evlrs.push(Vlr {
                user_id: "heritage".into(),
                record_id: k,
                description: format!("blob {k}"),
                data: (0..size).map(|i| (i * 7 + k as usize) as u8).collect(),
            });
        }
    }
    let header = b.into_header().unwrap();
    let file = std::fs::File::create(path).unwrap();
    let mut w = Writer::new(std::io::BufWriter::new(file), header).unwrap();
    let mut f = format;
    f.is_compressed = false;
    let pd = PointDataBuilder::new()
        .with_format(f)
        .with_transforms(transforms())
        .build_from_bytes(recs.clone())
        .unwrap();
    w.write_points(&pd).unwrap();
    w.close().unwrap();
    recs
}

/// The records, header and format of a file, read with the `las` crate.
pub(crate) fn read_back(path: &Path) -> (las::Header, Vec<u8>) {
    let mut r = Reader::from_path(path).unwrap();
    let pd = r.read_all().unwrap();
    (r.header().clone(), pd.raw_bytes().to_vec())
}

pub(crate) fn ao_values(n: usize) -> Vec<f32> {
    (0..n).map(|k| ((k * 37) % 101) as f32 / 100.0).collect()
}

pub(crate) fn u16_at(r: &[u8], at: usize) -> u16 {
    u16::from_le_bytes([r[at], r[at + 1]])
}
