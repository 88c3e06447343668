//! Decoding scalar columns of an element in one pass over its rows.

use super::*;
use rayon::prelude::*;

impl PlyFile {
    /// `f` of the values of scalar properties `props` of `element`, one result per row, in
    /// one pass (in parallel for fixed-size rows). `None` when the element or a property is
    /// missing or a list, or a fixed-size row is too short for a property; a value that cannot
    /// be read in a fixed-size row is NaN, in other layouts it makes the whole answer `None`.
    pub fn map_scalars<const K: usize, T: Send>(
        &self,
        element: &str,
        props: [&str; K],
        f: impl Fn([f64; K]) -> T + Sync,
    ) -> Option<Vec<T>> {
        let (def, data) = self.element_parts(element)?;
        let mut cols = [(0usize, ScalarType::U8); K];
        for (c, name) in cols.iter_mut().zip(props) {
            let i = def.props.iter().position(|p| p.name == name)?;
            let PropertyKind::Scalar(t) = def.props.get(i)?.kind else {
                return None;
            };
            *c = (i, t);
        }
        let layout = Layout::of(def, data)?;
        let mut out = Vec::with_capacity(def.count);
        match layout {
            Layout::Fixed { stride, bytes } => {
                let mut at = [(0usize, ScalarType::U8); K];
                for (a, &(i, t)) in at.iter_mut().zip(&cols) {
                    let off = field_offset(&def.props, &[], i)?;
                    if off + t.size() > stride {
                        return None;
                    }
                    *a = (off, t);
                }
                // In range for every row (checked above), so each read succeeds. `$read` reads
                // column `c` of a row.
                macro_rules! rows {
                    ($read:expr) => {
                        bytes
                            .par_chunks_exact(stride.max(1))
                            .map(|row| f(std::array::from_fn(|c| $read(row, c))))
                            .collect_into_vec(&mut out)
                    };
                }
                match uniform_type(&at) {
                    Some(t) => {
                        let offs = at.map(|a| a.0);
                        macro_rules! typed {
                            ($l:ty) => {
                                rows!(|row: &[u8], c: usize| <$l>::at(row, offs[c]))
                            };
                        }
                        uniform_dispatch!(t, typed)
                    }
                    None => rows!(|row: &[u8], c: usize| {
                        let (o, t): (usize, ScalarType) = at[c];
                        t.read_f64(row, o).unwrap_or(f64::NAN)
                    }),
                }
            }
            Layout::Rows { .. } => {
                layout.for_each_row(|row| {
                    let mut v = [0.0f64; K];
                    for (v, &(i, t)) in v.iter_mut().zip(&cols) {
                        *v = t.read_f64(row, field_offset(&def.props, row, i)?)?;
                    }
                    out.push(f(v));
                    Some(())
                })?;
            }
        }
        Some(out)
    }

    /// For each of the scalar properties `props` of `element`, how many rows hold a value
    /// `bad` says yes to: one pass over the rows with no per-row output (in parallel for
    /// fixed-size rows). `None` in the cases where [`map_scalars`](Self::map_scalars) gives
    /// `None`; a value that cannot be read in a fixed-size row counts as NaN.
    pub fn count_scalars(
        &self,
        element: &str,
        props: &[&str],
        bad: impl Fn(f64) -> bool + Sync,
    ) -> Option<Vec<usize>> {
        let (def, data) = self.element_parts(element)?;
        let mut cols = Vec::with_capacity(props.len());
        for name in props {
            let i = def.props.iter().position(|p| p.name == *name)?;
            let PropertyKind::Scalar(t) = def.props.get(i)?.kind else {
                return None;
            };
            cols.push((i, t));
        }
        let k = cols.len();
        let add = |mut a: Vec<usize>, b: Vec<usize>| {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
            a
        };
        match Layout::of(def, data)? {
            Layout::Fixed { stride, bytes } => {
                let mut at = Vec::with_capacity(k);
                for &(i, t) in &cols {
                    let off = field_offset(&def.props, &[], i)?;
                    if off + t.size() > stride {
                        return None;
                    }
                    at.push((off, t));
                }
                const ROWS: usize = 1 << 14;
                // `$read` reads column `c` of a row.
                macro_rules! counts {
                    ($read:expr) => {
                        bytes
                            .par_chunks(stride.max(1) * ROWS)
                            .map(|rows| {
                                let mut n = vec![0usize; k];
                                for row in rows.chunks_exact(stride.max(1)) {
                                    for (c, n) in n.iter_mut().enumerate() {
                                        *n += usize::from(bad($read(row, c)));
                                    }
                                }
                                n
                            })
                            .reduce(|| vec![0; k], add)
                    };
                }
                Some(match uniform_type(&at) {
                    Some(t) => {
                        let offs: Vec<usize> = at.iter().map(|a| a.0).collect();
                        macro_rules! typed {
                            ($l:ty) => {
                                counts!(|row: &[u8], c: usize| <$l>::at(row, offs[c]))
                            };
                        }
                        uniform_dispatch!(t, typed)
                    }
                    None => counts!(|row: &[u8], c: usize| {
                        let (o, t): (usize, ScalarType) = at[c];
                        t.read_f64(row, o).unwrap_or(f64::NAN)
                    }),
                })
            }
            layout @ Layout::Rows { .. } => {
                let mut n = vec![0usize; k];
                layout.for_each_row(|row| {
                    for (n, &(i, t)) in n.iter_mut().zip(&cols) {
                        *n += usize::from(bad(t.read_f64(row, field_offset(&def.props, row, i)?)?));
                    }
                    Some(())
                })?;
                Some(n)
            }
        }
    }

    /// Positions `[x, y, z]` of the `vertex` element (properties `x`, `y`, `z` of any scalar
    /// type, converted to f64), decoded in one pass over the rows: a fixed-stride walk when the
    /// element has no list property, the row offsets otherwise. `None` if there is no `vertex`
    /// element, one of `x`, `y`, `z` is missing or is a list, or the stored rows do not match
    /// the header.
    pub fn vertex_xyz(&self) -> Option<Vec<[f64; 3]>> {
        let (def, data) = self.element_parts("vertex")?;
        let find = |name: &str| -> Option<(usize, ScalarType)> {
            let i = def.props.iter().position(|p| p.name == name)?;
            match def.props.get(i)?.kind {
                PropertyKind::Scalar(t) => Some((i, t)),
                PropertyKind::List { .. } => None,
            }
        };
        let (ix, tx) = find("x")?;
        let (iy, ty) = find("y")?;
        let (iz, tz) = find("z")?;
        let layout = Layout::of(def, data)?;
        let mut out = Vec::with_capacity(def.count);
        match layout {
            Layout::Fixed { stride, bytes } => {
                let ox = field_offset(&def.props, &[], ix)?;
                let oy = field_offset(&def.props, &[], iy)?;
                let oz = field_offset(&def.props, &[], iz)?;
                if [(ox, tx), (oy, ty), (oz, tz)]
                    .iter()
                    .any(|&(o, t)| o + t.size() > stride)
                {
                    return None;
                }
                // In range for every row (checked above), so each read succeeds.
                let rd =
                    |t: ScalarType, row: &[u8], o: usize| t.read_f64(row, o).unwrap_or(f64::NAN);
                let rows = bytes.par_chunks_exact(stride.max(1));
                if [tx, ty, tz] == [ScalarType::F32; 3] {
                    let f = |row: &[u8], o: usize| {
                        le_array(row, o).map_or(f64::NAN, |b| f64::from(f32::from_le_bytes(b)))
                    };
                    rows.map(|row| [f(row, ox), f(row, oy), f(row, oz)])
                        .collect_into_vec(&mut out);
                } else {
                    rows.map(|row| [rd(tx, row, ox), rd(ty, row, oy), rd(tz, row, oz)])
                        .collect_into_vec(&mut out);
                }
            }
            Layout::Rows { .. } => {
                layout.for_each_row(|row| {
                    let ox = field_offset(&def.props, row, ix)?;
                    let oy = field_offset(&def.props, row, iy)?;
                    let oz = field_offset(&def.props, row, iz)?;
                    out.push([
                        tx.read_f64(row, ox)?,
                        ty.read_f64(row, oy)?,
                        tz.read_f64(row, oz)?,
                    ]);
                    Some(())
                })?;
            }
        }
        Some(out)
    }
}
