//! Converts a PLY file (ascii, binary little or big endian) to binary little endian, keeping
//! every element, property type, comment and `obj_info` line.
//!
//! ```text
//! cargo run --release --example ply_convert -- IN.ply OUT.ply
//! ```

use mvao::io::ply::PlyFile;
use std::path::PathBuf;
use std::process::ExitCode;

fn main() -> ExitCode {
    let args: Vec<PathBuf> = std::env::args_os().skip(1).map(PathBuf::from).collect();
    let [input, output] = args.as_slice() else {
        eprintln!("usage: ply_convert IN.ply OUT.ply");
        return ExitCode::from(2);
    };
    let ply = match PlyFile::from_path(input) {
        Ok(p) => p,
        Err(e) => {
            eprintln!("error: {e}");
            return ExitCode::FAILURE;
        }
    };
    if let Err(e) = ply.write_path(output) {
        eprintln!("error: {e}");
        return ExitCode::FAILURE;
    }
    let elements: Vec<String> = ply
        .header
        .elements
        .iter()
        .map(|e| format!("{} {}", e.name, e.count))
        .collect();
    println!(
        "{} -> {} ({:?} -> binary_little_endian; {})",
        input.display(),
        output.display(),
        ply.header.encoding,
        elements.join(", ")
    );
    ExitCode::SUCCESS
}
