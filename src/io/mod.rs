//! Reading scans and alignments from files, writing results. Bytes in, [`Scan`](crate::scan::Scan)s
//! out; no normals, pixels or progress bars here.

pub mod align;
pub mod atomic;
pub mod dataset;
pub mod direct;
pub mod e57_file;
pub mod las_file;
mod laz_check;
pub mod output;
pub mod ply;
mod ply_retain;
pub mod ptx;
pub mod raw;
pub mod reference;
pub mod results;
pub mod scan_ply;
pub mod source;
