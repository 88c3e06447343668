//! Parsing the header: magic, format, comments, elements and their properties.

use super::read::*;
use super::*;

/// Reads the header up to and including the `end_header` line.
pub(super) fn parse_header(src: &mut Source) -> Result<Header> {
    let mut line = Vec::with_capacity(256);
    let n = src.read_line(&mut line).map_err(|e| src.io_err(e))?;
    let first = line.get(..n).unwrap_or(&[]);
    if first.strip_suffix(b"\n").unwrap_or(first).trim_ascii() != b"ply" {
        return Err(src.err("not a PLY file (missing 'ply' magic)"));
    }
    let mut encoding = None;
    let mut comments = Vec::new();
    let mut obj_info = Vec::new();
    let mut elements: Vec<ElementDef> = Vec::new();
    let mut line_no = 1usize;
    loop {
        line_no += 1;
        if src.pos > MAX_HEADER_BYTES {
            return Err(src.err(format!(
                "header is longer than {MAX_HEADER_BYTES} bytes without 'end_header'"
            )));
        }
        let n = src.read_line(&mut line).map_err(|e| src.io_err(e))?;
        if n == 0 {
            return Err(src.err("header ends before 'end_header'"));
        }
        if line.last() != Some(&b'\n') && n as u64 == MAX_HEADER_LINE {
            return Err(src.err(format!(
                "line {line_no}: header line longer than {MAX_HEADER_LINE} bytes"
            )));
        }
        let text = String::from_utf8_lossy(&line);
        let text = text.trim_end_matches(['\n', '\r']).trim_start();
        if text.is_empty() {
            continue;
        }
        let (kw, rest) = text
            .split_once(|c: char| c.is_ascii_whitespace())
            .unwrap_or((text, ""));
        let words: Vec<&str> = rest.split_ascii_whitespace().collect();
        match kw {
            "format" => {
                if encoding.is_some() {
                    return Err(src.err(format!("line {line_no}: second 'format' line")));
                }
                let [fmt, version] = words.as_slice() else {
                    return Err(src.err(format!(
                        "line {line_no}: malformed format line '{text}' (expected 'format <encoding> 1.0')"
                    )));
                };
                encoding = Some(match *fmt {
                    "ascii" => Encoding::Ascii,
                    "binary_little_endian" => Encoding::BinaryLe,
                    "binary_big_endian" => Encoding::BinaryBe,
                    other => {
                        return Err(src.err(format!("line {line_no}: unknown format '{other}'")))
                    }
                });
                if version.parse::<f64>().ok() != Some(1.0) {
                    return Err(src.err(format!(
                        "line {line_no}: unsupported ply version '{version}'"
                    )));
                }
            }
            // A carriage return inside the text becomes a space, as the writer does, so a
            // written file reads back the same.
            "comment" => comments.push(one_line(rest.trim_start())),
            "obj_info" => obj_info.push(one_line(rest.trim_start())),
            "element" => {
                let [name, count] = words.as_slice() else {
                    return Err(src.err(format!(
                        "line {line_no}: malformed element line '{text}' (expected 'element <name> <count>')"
                    )));
                };
                let count = count.parse::<usize>().map_err(|_| {
                    src.err(format!(
                        "line {line_no}: element count '{count}' is not a non-negative integer"
                    ))
                })?;
                if elements.iter().any(|e| e.name == *name) {
                    return Err(src.err(format!(
                        "line {line_no}: element '{name}' is declared twice"
                    )));
                }
                elements.push(ElementDef {
                    name: (*name).to_string(),
                    count,
                    props: Vec::new(),
                });
            }
            "property" => {
                let Some(el) = elements.last_mut() else {
                    return Err(src.err(format!(
                        "line {line_no}: property declared before any element"
                    )));
                };
                let ty = |s: &str| {
                    ScalarType::parse(s).ok_or_else(|| {
                        src.err(format!("line {line_no}: unknown property type '{s}'"))
                    })
                };
                let prop = match words.as_slice() {
                    ["list", ct, it, name] => {
                        let count = ty(ct)?;
                        if count.int_range().is_none() {
                            return Err(src.err(format!(
                                "line {line_no}: list count type '{ct}' is not an integer type"
                            )));
                        }
                        Property {
                            name: (*name).to_string(),
                            kind: PropertyKind::List {
                                count,
                                item: ty(it)?,
                            },
                        }
                    }
                    [t, name] if *t != "list" => Property {
                        name: (*name).to_string(),
                        kind: PropertyKind::Scalar(ty(t)?),
                    },
                    _ => {
                        return Err(
                            src.err(format!("line {line_no}: malformed property line '{text}'"))
                        )
                    }
                };
                if el.props.iter().any(|p| p.name == prop.name) {
                    return Err(src.err(format!(
                        "line {line_no}: element '{}' declares property '{}' twice",
                        el.name, prop.name
                    )));
                }
                el.props.push(prop);
            }
            "end_header" => break,
            other => {
                return Err(src.err(format!("line {line_no}: unknown header keyword '{other}'")))
            }
        }
    }
    let encoding = encoding.ok_or_else(|| src.err("header has no 'format' line"))?;
    Ok(Header {
        encoding,
        comments,
        obj_info,
        elements,
    })
}
