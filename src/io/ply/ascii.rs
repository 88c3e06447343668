//! Reading ascii bodies: one row a line, tokens parsed to the declared types.

use super::read::*;
use super::*;

/// Why an ascii token is not a value of its type.
pub(super) enum AsciiProblem {
    NotNumber,
    NotInteger,
    OutOfRange,
}

/// Parses an ascii integer (`12`, `-3`, `+4`, or a whole number written as a float, `5.0`).
pub(super) fn parse_int(tok: &[u8]) -> std::result::Result<i64, AsciiProblem> {
    let s = std::str::from_utf8(tok).map_err(|_| AsciiProblem::NotNumber)?;
    if let Ok(v) = s.parse::<i64>() {
        return Ok(v);
    }
    match s.parse::<f64>() {
        Ok(f) if f.is_finite() && f.fract() == 0.0 => {
            if (-9.2e18..=9.2e18).contains(&f) {
                Ok(f as i64)
            } else {
                Err(AsciiProblem::OutOfRange)
            }
        }
        Ok(f) if f.is_infinite() => Err(AsciiProblem::OutOfRange),
        Ok(_) => Err(AsciiProblem::NotInteger),
        Err(_) => Err(AsciiProblem::NotNumber),
    }
}

/// Parses an ascii token as type `t`, little endian.
pub(super) fn parse_ascii(tok: &[u8], t: ScalarType) -> std::result::Result<Encoded, AsciiProblem> {
    match t {
        ScalarType::F32 => {
            let s = std::str::from_utf8(tok).map_err(|_| AsciiProblem::NotNumber)?;
            let v = s.parse::<f32>().map_err(|_| AsciiProblem::NotNumber)?;
            let mut e = Encoded {
                buf: [0; 8],
                len: 4,
            };
            e.buf[..4].copy_from_slice(&v.to_le_bytes());
            Ok(e)
        }
        ScalarType::F64 => {
            let s = std::str::from_utf8(tok).map_err(|_| AsciiProblem::NotNumber)?;
            let v = s.parse::<f64>().map_err(|_| AsciiProblem::NotNumber)?;
            Ok(Encoded {
                buf: v.to_le_bytes(),
                len: 8,
            })
        }
        _ => {
            let v = parse_int(tok)?;
            let (lo, hi) = t.int_range().unwrap_or((0, 0));
            if v < lo || v > hi {
                return Err(AsciiProblem::OutOfRange);
            }
            // Exact: the value is a whole number within the type's range.
            Ok(t.encode(v as f64))
        }
    }
}

/// A token for an error message (lossy, shortened).
pub(super) fn show(tok: &[u8]) -> String {
    let s = String::from_utf8_lossy(tok);
    if s.chars().count() > 40 {
        format!("{}…", s.chars().take(40).collect::<String>())
    } else {
        s.into_owned()
    }
}

/// An ascii element, token by token, with one reused token buffer. Each row is one line: a
/// line with too few or too many values for the element's properties is an error naming it.
pub(super) fn read_ascii(src: &mut Source, def: &ElementDef) -> Result<ElementData> {
    let stride = fixed_stride(&def.props);
    let has_lists = stride.is_none();
    // Every ascii value takes at least two bytes (a digit and a separator).
    let min_row = def.props.len().saturating_mul(2).max(1);
    let max_rows = src.reserve_cap() / min_row + 1;
    let rows_cap = def.count.min(max_rows);
    let mut bytes = Vec::with_capacity(rows_cap.saturating_mul(stride.unwrap_or(min_row)));
    let mut offs = if has_lists {
        let mut o = Vec::with_capacity(rows_cap.saturating_add(1));
        o.push(0);
        Some(o)
    } else {
        None
    };
    let lists = def
        .props
        .iter()
        .filter(|p| matches!(p.kind, PropertyKind::List { .. }))
        .count();
    let mut tok = Vec::with_capacity(64);
    for row in 0..def.count {
        // Blank lines before a row are skipped; the row's first value fixes its line.
        next_ascii(src, &mut tok, def, row)?;
        let mut shape = RowShape {
            line: src.line,
            got: 0,
            want: def.props.len(),
            open_lists: lists,
        };
        for (pi, p) in def.props.iter().enumerate() {
            let (value_type, is_list) = match p.kind {
                PropertyKind::Scalar(t) => (t, None),
                PropertyKind::List { count, item } => (count, Some(item)),
            };
            if pi > 0 {
                shape.next(src, &mut tok, def, row)?;
            }
            shape.got += 1;
            let Some(item) = is_list else {
                let v = parse_ascii(&tok, value_type)
                    .map_err(|e| ascii_error(src, &tok, e, value_type, def, row, &p.name))?;
                bytes.extend_from_slice(v.as_slice());
                continue;
            };
            let n = match parse_int(&tok) {
                Ok(n) if n < 0 => {
                    return Err(src.err(format!(
                        "element '{}' row {row}: list count {n} is negative",
                        def.name
                    )))
                }
                Ok(n) => n,
                Err(e) => return Err(ascii_error(src, &tok, e, value_type, def, row, &p.name)),
            };
            let (_, hi) = value_type.int_range().unwrap_or((0, 0));
            if n > hi {
                return Err(src.err(format!(
                    "element '{}' row {row}: list count {n} is too large for its type {}",
                    def.name,
                    value_type.name()
                )));
            }
            shape.open_lists -= 1;
            shape.want = shape.want.saturating_add(n as usize);
            bytes.extend_from_slice(value_type.encode(n as f64).as_slice());
            for _ in 0..n {
                shape.next(src, &mut tok, def, row)?;
                shape.got += 1;
                let v = parse_ascii(&tok, item)
                    .map_err(|e| ascii_error(src, &tok, e, item, def, row, &p.name))?;
                bytes.extend_from_slice(v.as_slice());
            }
        }
        let extra = src.rest_of_line().map_err(|e| src.io_err(e))?;
        if extra > 0 {
            shape.got += extra;
            return Err(shape.error(src, def, row));
        }
        if let Some(o) = offs.as_mut() {
            o.push(bytes.len());
        }
    }
    Ok(ElementData {
        bytes,
        row_offsets: offs,
    })
}

/// The values of one ascii row read so far, against those its properties call for.
pub(super) struct RowShape {
    /// The row's line.
    pub(super) line: u64,
    /// Values read.
    pub(super) got: usize,
    /// Values called for: one per scalar and list count, plus the items of the lists read.
    pub(super) want: usize,
    /// Lists whose count is not read yet (each may call for more values).
    pub(super) open_lists: usize,
}

impl RowShape {
    /// The next value of the row, which must be on the row's line.
    pub(super) fn next(
        &self,
        src: &mut Source,
        tok: &mut Vec<u8>,
        def: &ElementDef,
        row: usize,
    ) -> Result<()> {
        next_ascii(src, tok, def, row)?;
        if src.line != self.line {
            return Err(self.error(src, def, row));
        }
        Ok(())
    }

    /// The error of a row with the wrong number of values.
    pub(super) fn error(&self, src: &Source, def: &ElementDef, row: usize) -> Error {
        let at_least = if self.open_lists > 0 { "at least " } else { "" };
        src.err(format!(
            "line {}: {} {row} has {} values, expected {at_least}{}",
            self.line, def.name, self.got, self.want
        ))
    }
}

/// The next ascii token of element `def`, row `row`, or the matching error.
pub(super) fn next_ascii(
    src: &mut Source,
    tok: &mut Vec<u8>,
    def: &ElementDef,
    row: usize,
) -> Result<()> {
    match src.next_token(tok).map_err(|e| src.io_err(e))? {
        None => Err(truncated(src, def, row)),
        Some(false) => Err(src.err(format!(
            "line {}: ascii value '{}' in element '{}' row {row} is longer than {MAX_TOKEN} \
             characters",
            src.line,
            show(tok),
            def.name
        ))),
        Some(true) => Ok(()),
    }
}

pub(super) fn ascii_error(
    src: &Source,
    tok: &[u8],
    e: AsciiProblem,
    t: ScalarType,
    def: &ElementDef,
    row: usize,
    prop: &str,
) -> Error {
    let what = match e {
        AsciiProblem::NotNumber => "is not a number".to_string(),
        AsciiProblem::NotInteger => format!("is not an integer (type {})", t.name()),
        AsciiProblem::OutOfRange => format!("is out of range for type {}", t.name()),
    };
    src.err(format!(
        "line {}: ascii value '{}' in element '{}' row {row} {what} (property '{prop}')",
        src.line,
        show(tok),
        def.name
    ))
}
