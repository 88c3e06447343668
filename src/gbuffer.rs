//! gbuffer
