//! `mvao info` as text for the terminal (`--json` prints the same description as JSON).

use mvao::info::Info;
use std::fmt::Write as _;

/// `info` as text, one block per scan.
pub fn text(info: &Info) -> String {
    let mut o = String::new();
    if let Some(a) = &info.alignment {
        let _ = writeln!(o, "alignment: {a}");
    }
    for w in &info.warnings {
        let _ = writeln!(o, "warning: {w}");
    }
    for p in &info.problems {
        let _ = writeln!(o, "error: {p}");
    }
    for s in &info.scans {
        let _ = writeln!(o, "{} ({}, {})", s.name, s.file, s.format);
        let _ = writeln!(
            o,
            "  points:     {} of {} records valid",
            s.points, s.records
        );
        let _ = writeln!(o, "  attributes: {}", s.attributes.join(" "));
        match (s.grid, s.grid_filled) {
            (Some([r, c]), Some(f)) => {
                let _ = writeln!(
                    o,
                    "  grid:       {r} rows × {c} columns, {:.1} % filled",
                    100.0 * f
                );
            }
            _ => {
                let _ = writeln!(o, "  grid:       none");
            }
        }
        let _ = writeln!(o, "  pose:       from {}", s.pose_source);
        for r in &s.pose {
            let _ = writeln!(
                o,
                "              {:>14.6} {:>14.6} {:>14.6} {:>16.6}",
                r[0], r[1], r[2], r[3]
            );
        }
        let _ = writeln!(
            o,
            "  scanner:    ({:.3}, {:.3}, {:.3})",
            s.scanner[0], s.scanner[1], s.scanner[2]
        );
        let _ = writeln!(
            o,
            "  sensor:     {} {}×{} — {}",
            s.sensor_model, s.map_size[0], s.map_size[1], s.sensor_reason
        );
        let _ = writeln!(
            o,
            "  bounds:     ({:.3}, {:.3}, {:.3}) – ({:.3}, {:.3}, {:.3})",
            s.bounds[0][0],
            s.bounds[0][1],
            s.bounds[0][2],
            s.bounds[1][0],
            s.bounds[1][1],
            s.bounds[1][2]
        );
        let _ = writeln!(
            o,
            "  overlaps:   {}",
            if s.overlaps.is_empty() {
                "none".to_string()
            } else {
                s.overlaps.join(", ")
            }
        );
    }
    o
}
