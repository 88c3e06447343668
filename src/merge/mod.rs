//! Merging views.
pub mod border;
