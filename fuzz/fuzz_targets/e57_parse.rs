#![no_main]
//! `e57_parse`: the bytes as the pages of an `.e57` file, see `mvao_fuzz::check_e57`.

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| mvao_fuzz::check_e57(data));
