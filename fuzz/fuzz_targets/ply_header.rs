#![no_main]
//! `ply_header`: see `mvao_fuzz::check_ply_structured`.

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| mvao_fuzz::check_ply_structured(data));
