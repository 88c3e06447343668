#![no_main]
//! `ply_parse`: see `mvao_fuzz::check_ply`.

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| mvao_fuzz::check_ply(data));
