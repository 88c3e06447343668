//! # mvao — multi-view ambient occlusion for raw aligned 3D scans
//!
//! Each scan is rendered into a G-buffer from its own sensor position, screen-space ambient
//! occlusion is computed per scan, and all views are merged with distance, direction and border
//! weights into one AO value per point (Sabbadin et al. 2016, with the decisions of the project's
//! specification).
//!
//! The public API is what a caller needs: [`pipeline::run`] (the `mvao merge` job over files,
//! writing results and a [`Report`]) and [`pipeline::compute`] (the same stages over scans in
//! memory), their [`config`], the readers and writers in [`io`], the [`progress`] observer
//! through which the library reports (it never prints), the virtual scanner in [`synth`], and
//! the reference and evaluation jobs in [`accuracy`].
//!
//! The same computation the command line runs, on a scan from the virtual scanner:
//!
//! ```
//! use glam::DVec3;
//! use mvao::config::ComputeParams;
//! use mvao::pipeline::compute;
//! use mvao::progress::Silent;
//! use mvao::Estimator;
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
// Library code returns errors: a panic would take the caller's process down.
#![cfg_attr(
    not(test),
    deny(clippy::unwrap_used, clippy::expect_used, clippy::panic)
)]
// Guards are written `!(x > 0.0)` on purpose: they also reject NaN.
#![allow(clippy::neg_cmp_op_on_partial_ord)]

pub mod accuracy;
pub mod bigalloc;
pub mod config;
pub mod error;
pub(crate) mod eval;
pub mod falloff;
pub(crate) mod gbuffer;
pub mod info;
pub mod io;
pub(crate) mod merge;
pub(crate) mod pagebuf;
pub(crate) mod par;
pub mod pipeline;
pub(crate) mod plot;
pub(crate) mod preview;
pub(crate) mod products;
pub mod progress;
pub(crate) mod projection;
pub(crate) mod radius;
pub(crate) mod reference;
pub mod report;
pub(crate) mod rng;
pub(crate) mod scan;
pub(crate) mod sensor;
pub(crate) mod site;
pub(crate) mod ssao;
pub(crate) mod store;
pub mod stream;
pub mod sweep;
pub mod synth;
pub(crate) mod sys;
pub(crate) mod view;

pub use error::{Error, Result};
pub use falloff::Falloff;
pub use merge::union::{Occlusion, FILTER_RADIUS as UNION_FILTER, MAX_VIEWS as UNION_VIEWS};
pub use preview::{PreviewStyle, Tone, Up};
pub use projection::SensorModel;
pub use reference::{RefParams, OPEN_MIN_A};
pub use report::Report;
pub use scan::Scan;
pub use sensor::ProjectionChoice;
pub use ssao::{Estimator, Sampling};

/// Internals for the crate's own tests, benches, examples and fuzz targets: not part of the
/// API and free to change. Each module keeps its inner paths (`testing::scan::knn::…`).
#[doc(hidden)]
pub mod testing {
    // A crate-private module cannot itself be re-exported, so each is mirrored by a module
    // re-exporting its public items (nested public modules included).
    pub mod eval {
        pub use crate::eval::*;
    }
    pub mod gbuffer {
        pub use crate::gbuffer::*;
    }
    pub mod merge {
        pub use crate::merge::*;
    }
    pub mod preview {
        pub use crate::preview::*;
    }
    pub mod products {
        pub use crate::products::*;
    }
    pub mod projection {
        pub use crate::projection::*;
    }
    pub mod reference {
        pub use crate::reference::*;
    }
    pub mod rng {
        pub use crate::rng::*;
    }
    pub mod scan {
        pub use crate::scan::*;
    }
    pub mod sensor {
        pub use crate::sensor::*;
    }
    pub mod ssao {
        pub use crate::ssao::*;
    }
    pub mod view {
        pub use crate::view::*;
    }
    pub mod pipeline {
        pub use crate::pipeline::*;
        pub mod plan {
            pub use crate::pipeline::plan::*;
        }
        pub mod occlusion {
            pub use crate::pipeline::occlusion::*;
        }
    }
    pub mod sys {
        pub use crate::sys::*;
    }
}
