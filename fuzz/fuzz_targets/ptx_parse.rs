#![no_main]
//! `ptx_parse`: the bytes as a `.ptx` file, see `mvao_fuzz::check_ptx`.

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| mvao_fuzz::check_ptx(data));
