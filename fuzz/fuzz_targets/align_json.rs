#![no_main]
//! `align_json`: the bytes as an `alignment.json` file, see `mvao_fuzz::check_align`.

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| mvao_fuzz::check_align("json", data));
