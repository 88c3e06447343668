#![no_main]
//! `align_aln`: the bytes as an `alignment.aln` file, see `mvao_fuzz::check_align`.

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| mvao_fuzz::check_align("aln", data));
