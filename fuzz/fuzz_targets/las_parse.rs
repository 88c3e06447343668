#![no_main]
//! `las_parse`: a `.las` or `.laz` file (first byte), see `mvao_fuzz::check_las`.

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    mvao_fuzz::scans::report_caught_panics();
    mvao_fuzz::check_las(data)
});
