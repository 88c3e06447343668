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
//!
//! The same computation the command line runs, on a scan from the virtual scanner:
//!
//! ```
//! use glam::DVec3;
//! use mvao::config::ComputeParams;
//! use mvao::pipeline::compute;
//! use mvao::progress::Silent;
//! use mvao::ssao::Estimator;
//! use mvao::synth::{scan_scene, Scene, Station};
//!
//! let station = Station::equirect(DVec3::new(0.0, 0.0, 1.5), 0.0, 360, 180);
//! let mut scan = scan_scene(&Scene::room(), &station, 0.0, 1, "station");
//! scan.pose = station.pose();
//! let params = ComputeParams {
//!     radius: Some(0.2),
//!     tmax: Some(0.4),
//!     estimator: Estimator::Horizon,
//!     ..Default::default()
//! };
//! let out = compute(&[scan], &params, &Silent)?;
//! let ao = &out.scans[0].ao;
//! assert!(ao.iter().all(|a| (0.0..=1.0).contains(a)));
//! // Most of a room is open floor, wall and ceiling; corners are darker.
//! let open = ao.iter().filter(|&&a| a > 0.95).count();
//! assert!(open > ao.len() / 2);
//! # Ok::<(), mvao::Error>(())
//! ```
#![deny(missing_docs)]
// Guards are written `!(x > 0.0)` on purpose: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod accuracy;
pub mod config;
pub mod error;
pub mod eval;
pub mod gbuffer;
pub mod info;
pub mod io;
pub mod merge;
pub mod pagebuf;
pub mod par;
pub mod pipeline;
pub mod plot;
pub mod preview;
pub mod products;
pub mod progress;
pub mod projection;
pub mod radius;
pub mod reference;
pub mod report;
pub mod rng;
pub mod scan;
pub mod sensor;
pub mod site;
pub mod ssao;
pub mod store;
pub mod sweep;
pub mod synth;
pub mod sys;
pub mod view;

pub use error::{Error, Result};
