//! ssao
