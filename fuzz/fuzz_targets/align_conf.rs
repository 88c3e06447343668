#![no_main]
//! `align_conf`: the bytes as an `alignment.conf` file, see `mvao_fuzz::check_align`.

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| mvao_fuzz::check_align("conf", data));
