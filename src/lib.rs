//! # mvao — multi-view ambient occlusion for raw aligned 3D scans
//!
//! Each scan is rendered into a G-buffer from its own sensor position, screen-space ambient
//! occlusion is computed per scan, and all views are merged with distance, direction and border
//! weights into one AO value per point (Sabbadin et al. 2016, with the decisions of the project's
//! specification). The stages mirror the modules:
//!
//! [`io`] reads scans and alignments → [`scan`] adds normals and radii → [`projection`] maps
//! points to pixels → [`gbuffer`] rasterizes → [`ssao`] shades each view → [`merge`] combines the
//! views → [`pipeline`] orders all of it and [`report`] records what happened.
#![deny(missing_docs)]
// Guards are written `!(x > 0.0)` on purpose: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod cli;
pub mod error;
pub mod gbuffer;
pub mod io;
pub mod merge;
pub mod pipeline;
pub mod projection;
pub mod report;
pub mod scan;
pub mod sensor;
pub mod ssao;
pub mod synth;

pub use error::{Error, Result};
