//! Alignment files.
