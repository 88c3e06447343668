//! Bounds on a LAZ file's chunk layout, checked before the decompressor sees it.
//!
//! The LAZ decoder trusts the sizes written in the file: a layered chunk (point formats 6–10)
//! starts with one byte count per layer, and the decoder allocates each layer's buffer before
//! reading it, so four corrupt bytes ask for up to 4 GiB. Every chunk's sizes are checked here
//! against the chunk table and the file's length, so a corrupt file costs what it weighs.
//! With variable-size chunks the decoder looks up each chunk's point count in the table and
//! indexes past its end when the table describes fewer points than the header: that is
//! refused here too.

use std::path::Path;

#[cfg(feature = "laz")]
use crate::error::Error;
use crate::error::Result;

/// Checks the chunk table (layered compression or variable-size chunks) and, for layered
/// compression, every chunk's layer sizes.
/// `laszip_vlr` is the payload of the LASzip VLR; `offset` is the offset to point data and
/// `count` the header's point count.
#[cfg(feature = "laz")]
pub(crate) fn check_layers<R: std::io::Read + std::io::Seek>(
    f: &mut R,
    path: &Path,
    file_len: u64,
    offset: u64,
    count: u64,
    laszip_vlr: &[u8],
) -> Result<()> {
    use laz::laszip::{ChunkTable, LazItemType, LazVlr};
    use std::io::SeekFrom;

    let bad = |m: String| Error::format(path, m);
    let vlr = LazVlr::from_buffer(laszip_vlr).map_err(|e| bad(format!("bad LASzip VLR: {e}")))?;
    // Two layouts the decoder does not refuse but cannot read (it panics on them).
    if vlr.items().is_empty() {
        return Err(bad("bad LASzip VLR: it lists no point items".into()));
    }
    // Summed wide: the decoder's own sum is 16 bits and overflows on a corrupt VLR.
    let first_point: u64 = vlr.items().iter().map(|i| u64::from(i.size())).sum();
    if first_point > u64::from(u16::MAX) {
        return Err(bad(format!(
            "bad LASzip VLR: its items add up to {first_point} bytes a point"
        )));
    }
    let point_wise = laszip_vlr.get(..2) == Some(&[1, 0][..]);
    if point_wise && vlr.uses_variable_size_chunks() {
        return Err(bad(
            "bad LASzip VLR: variable-size chunks without chunked compression".into(),
        ));
    }
    let layers_of = |t: LazItemType| -> Option<u64> {
        match t {
            LazItemType::Point14 => Some(9),
            LazItemType::RGB14 | LazItemType::WavePacket14 => Some(1),
            LazItemType::RGBNIR14 => Some(2),
            LazItemType::Byte14(n) => Some(u64::from(n)),
            _ => None,
        }
    };
    let layered: Option<Vec<u64>> = vlr
        .items()
        .iter()
        .map(|i| layers_of(i.item_type()))
        .collect();
    if layered.is_none() && !vlr.uses_variable_size_chunks() {
        // Point-wise compression in fixed-size chunks reads its arithmetic-coded stream as it
        // goes: nothing to bound.
        return Ok(());
    }
    let n_layers: u64 = layered.as_ref().map_or(0, |l| l.iter().sum());
    // The smallest chunk: for layers the first point raw, the point count and the layer
    // sizes; point-wise, at least a byte.
    let min_chunk = if layered.is_some() {
        first_point + 4 + 4 * n_layers
    } else {
        1
    };

    f.seek(SeekFrom::Start(offset))
        .map_err(|e| Error::io(path, e))?;
    let table_at = read_table_offset(f, offset, file_len)
        .ok_or_else(|| bad("LAZ without a readable chunk table".into()))?;
    // The chunk count is plain bytes before the coded entries; bound it before the table
    // reader reserves memory for it.
    f.seek(SeekFrom::Start(table_at + 4))
        .map_err(|e| Error::io(path, e))?;
    let mut b4 = [0u8; 4];
    f.read_exact(&mut b4)
        .map_err(|_| bad("truncated LAZ chunk table".into()))?;
    let chunks = u64::from(u32::from_le_bytes(b4));
    let room = file_len.saturating_sub(offset + 8);
    if chunks.saturating_mul(min_chunk) > room {
        return Err(bad(format!(
            "corrupt LAZ chunk table ({chunks} chunks cannot fit in {room} bytes of point data)"
        )));
    }
    f.seek(SeekFrom::Start(offset))
        .map_err(|e| Error::io(path, e))?;
    let table = ChunkTable::read_from(&mut *f, &vlr)
        .map_err(|e| bad(format!("corrupt LAZ chunk table: {e}")))?;

    // The decoder reads chunk after chunk whatever the table says: a chunk the table does not
    // describe could not be bounded.
    let described: u64 = table.as_ref().iter().map(|e| e.point_count).sum();
    if described < count {
        return Err(bad(format!(
            "corrupt LAZ chunk table: it describes {described} points, the header says {count}"
        )));
    }
    if layered.is_none() {
        return Ok(());
    }
    let mut start = offset + 8;
    for (i, entry) in table.as_ref().iter().enumerate() {
        let end = start.saturating_add(entry.byte_count);
        if entry.byte_count < min_chunk || end > file_len {
            return Err(bad(format!(
                "corrupt LAZ chunk {i}: {} bytes at offset {start} in a {file_len}-byte file",
                entry.byte_count
            )));
        }
        f.seek(SeekFrom::Start(start + first_point + 4))
            .map_err(|e| Error::io(path, e))?;
        let mut sum = 0u64;
        for _ in 0..n_layers {
            f.read_exact(&mut b4)
                .map_err(|_| bad(format!("truncated LAZ chunk {i}")))?;
            sum += u64::from(u32::from_le_bytes(b4));
        }
        if sum > entry.byte_count - min_chunk {
            return Err(bad(format!(
                "corrupt LAZ chunk {i}: its layers claim {sum} bytes, the chunk holds {}",
                entry.byte_count - min_chunk
            )));
        }
        start = end;
    }
    Ok(())
}

/// Where the chunk table starts: the 8 bytes at the start of point data, or, when a writer could
/// not seek back to fill them, the file's last 8 bytes.
#[cfg(feature = "laz")]
fn read_table_offset<R: std::io::Read + std::io::Seek>(
    f: &mut R,
    offset: u64,
    file_len: u64,
) -> Option<u64> {
    use std::io::SeekFrom;
    let mut read_at = |at: u64| -> Option<u64> {
        let mut b = [0u8; 8];
        f.seek(SeekFrom::Start(at)).ok()?;
        f.read_exact(&mut b).ok()?;
        u64::try_from(i64::from_le_bytes(b)).ok()
    };
    let valid = |t: u64| t > offset && t.saturating_add(8) <= file_len;
    read_at(offset)
        .filter(|&t| valid(t))
        .or_else(|| read_at(file_len.checked_sub(8)?).filter(|&t| valid(t)))
}

/// Without LAZ support compressed files are refused before any check is needed.
#[cfg(not(feature = "laz"))]
pub(crate) fn check_layers<R>(_: &mut R, _: &Path, _: u64, _: u64, _: u64, _: &[u8]) -> Result<()> {
    Ok(())
}
