#![no_main]
//! `align_mlp`: the bytes as an `alignment.mlp` file, see `mvao_fuzz::check_align`.

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| mvao_fuzz::check_align("mlp", data));
