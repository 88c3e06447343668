//! Border distance field.
