//! Reading scans and alignments from files, writing results. Bytes in, [`Scan`](crate::scan::Scan)s
//! out; no normals, pixels or progress bars here.

pub mod align;
pub mod atomic;
pub mod dataset;
pub mod direct;
pub mod e57;
pub mod las;
pub mod output;
pub mod ply;
pub mod ptx;
pub mod raw;
pub mod reference;
pub mod results;
pub mod source;
