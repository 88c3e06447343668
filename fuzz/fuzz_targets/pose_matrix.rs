#![no_main]
//! `pose_matrix`: a sidecar or `--pose` matrix file, see `mvao_fuzz::check_matrix`.

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| mvao_fuzz::check_matrix(data));
