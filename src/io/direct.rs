//! Large sequential files past the page cache (Linux `O_DIRECT`) on local disk filesystems.
//!
//! A run writes its products and outputs once (about 100 bytes per point) and reads the
//! products back at most once or twice. Through the page cache each of those bytes is copied
//! by the kernel into a freshly allocated cache page, a cost that measured close to that of the
//! SSAO stage's slowest part on a 2-core machine, and the cache fills with data no one rereads
//! while the inputs, which are reread, get evicted. With `O_DIRECT` the disk reads from and
//! writes into this process's own buffer.
//!
//! Direct I/O is used only on ext2/3/4, XFS and btrfs, where it is well supported and fast;
//! other filesystems (network, tmpfs, FUSE), other systems, files smaller than one block of
//! [`BLOCK`] bytes, and a filesystem that refuses an aligned request all take the ordinary
//! path, with the same bytes in the file. `MVAO_DIRECT_IO=0` turns it off.

use std::fs::File;
use std::io::{self, Read, Write};
use std::path::Path;

/// Bytes per direct request; also the size below which a file takes the ordinary path.
pub const BLOCK: usize = 1 << 22;
/// Buffer, offset and length alignment of a direct request (the largest logical block size
/// of common disks).
const ALIGN: usize = 4096;

/// Whether direct I/O is wanted at all (`MVAO_DIRECT_IO=0` turns it off).
fn enabled() -> bool {
    static ON: std::sync::OnceLock<bool> = std::sync::OnceLock::new();
    *ON.get_or_init(|| std::env::var_os("MVAO_DIRECT_IO").is_none_or(|v| v != "0"))
}

/// A heap buffer of `BLOCK` bytes starting at an `ALIGN`ed address.
struct Aligned {
    mem: Vec<u8>,
    start: usize,
}

impl Aligned {
    fn new() -> Aligned {
        let mem = vec![0u8; BLOCK + ALIGN];
        let start = mem.as_ptr().align_offset(ALIGN).min(ALIGN);
        Aligned { mem, start }
    }

    fn buf(&mut self) -> &mut [u8] {
        &mut self.mem[self.start..self.start + BLOCK]
    }
}

#[cfg(target_os = "linux")]
mod sys {
    use std::fs::File;
    use std::os::fd::AsRawFd;

    /// Whether `file` lies on a local filesystem where direct I/O is dependable.
    pub fn suits(file: &File) -> bool {
        const EXT: i64 = 0xEF53;
        const XFS: i64 = 0x5846_5342;
        const BTRFS: i64 = 0x9123_683E;
        // SAFETY: fstatfs fills the zero-initialised plain-data struct for a descriptor that
        // `file` keeps open for the call.
        let kind = unsafe {
            let mut st: libc::statfs = std::mem::zeroed();
            if libc::fstatfs(file.as_raw_fd(), &mut st) != 0 {
                return false;
            }
            st.f_type as i64
        };
        matches!(kind, EXT | XFS | BTRFS)
    }

    /// Turns `O_DIRECT` on or off for `file`; false when the system refuses.
    pub fn set_direct(file: &File, on: bool) -> bool {
        let fd = file.as_raw_fd();
        // SAFETY: F_GETFL/F_SETFL read and set the status flags of a descriptor that `file`
        // keeps open; no memory is passed.
        unsafe {
            let flags = libc::fcntl(fd, libc::F_GETFL);
            if flags < 0 {
                return false;
            }
            let flags = if on {
                flags | libc::O_DIRECT
            } else {
                flags & !libc::O_DIRECT
            };
            libc::fcntl(fd, libc::F_SETFL, flags) == 0
        }
    }
}

#[cfg(not(target_os = "linux"))]
mod sys {
    use std::fs::File;

    pub fn suits(_file: &File) -> bool {
        false
    }

    pub fn set_direct(_file: &File, _on: bool) -> bool {
        false
    }
}

/// Turns direct I/O on for `file` when it is wanted and the filesystem suits it.
fn try_direct(file: &File) -> bool {
    enabled() && sys::suits(file) && sys::set_direct(file, true)
}

/// Whether an error says the filesystem refused the request's alignment or mode.
fn refused(e: &io::Error) -> bool {
    e.kind() == io::ErrorKind::InvalidInput
}

#[derive(Clone, Copy, PartialEq, Debug)]
enum Mode {
    /// Nothing written yet: the first full block decides.
    Open,
    Direct,
    Cached,
}

/// A buffered writer that sends whole aligned blocks past the page cache where it can
/// (see the module documentation); [`Writer::finish`] writes the rest and hands the file back.
pub struct Writer {
    file: File,
    buf: Aligned,
    /// Bytes waiting in `buf`.
    len: usize,
    /// Bytes accepted so far: the file's final length.
    total: u64,
    mode: Mode,
}

impl Writer {
    /// Wraps a newly created, empty `file`.
    pub fn new(file: File) -> Writer {
        Writer::with_direct(file, true)
    }

    /// [`Writer::new`], with direct I/O allowed only when `direct` (tests use both paths).
    pub fn with_direct(file: File, direct: bool) -> Writer {
        Writer {
            file,
            buf: Aligned::new(),
            len: 0,
            total: 0,
            mode: if direct { Mode::Open } else { Mode::Cached },
        }
    }

    /// Whether this writer has sent blocks past the page cache.
    pub fn is_direct(&self) -> bool {
        self.mode == Mode::Direct
    }

    /// Writes the buffer, whose length is a multiple of `ALIGN` in direct mode.
    fn send(&mut self, n: usize) -> io::Result<()> {
        if self.mode == Mode::Open {
            self.mode = if try_direct(&self.file) {
                Mode::Direct
            } else {
                Mode::Cached
            };
        }
        let mut off = 0;
        while off < n {
            let start = self.buf.start;
            let chunk = &self.buf.mem[start + off..start + n];
            match self.file.write(chunk) {
                Ok(0) => return Err(io::ErrorKind::WriteZero.into()),
                Ok(k) => {
                    off += k;
                    // A short direct write would leave the rest unaligned.
                    if self.mode == Mode::Direct && off % ALIGN != 0 {
                        self.cached()?;
                    }
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) if self.mode == Mode::Direct && refused(&e) => self.cached()?,
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }

    /// Leaves direct I/O for the rest of the file.
    fn cached(&mut self) -> io::Result<()> {
        if sys::set_direct(&self.file, false) {
            self.mode = Mode::Cached;
            Ok(())
        } else {
            Err(io::Error::other("cannot leave direct I/O"))
        }
    }

    /// Writes what is buffered and returns the file, `total` bytes long.
    pub fn finish(mut self) -> io::Result<File> {
        if self.len > 0 {
            if self.mode == Mode::Direct {
                // The last block goes out padded to the alignment, then the file is cut back.
                let padded = self.len.next_multiple_of(ALIGN);
                self.buf.buf()[self.len..padded].fill(0);
                self.send(padded)?;
                self.file.set_len(self.total)?;
            } else {
                self.mode = Mode::Cached;
                self.send(self.len)?;
            }
            self.len = 0;
        }
        Ok(self.file)
    }
}

impl Write for Writer {
    fn write(&mut self, data: &[u8]) -> io::Result<usize> {
        let k = data.len().min(BLOCK - self.len);
        let at = self.len;
        self.buf.buf()[at..at + k].copy_from_slice(&data[..k]);
        self.len += k;
        self.total += k as u64;
        if self.len == BLOCK {
            self.send(BLOCK)?;
            self.len = 0;
        }
        Ok(k)
    }

    /// Whole blocks only go out as they fill; the rest waits for [`Writer::finish`], which
    /// must be called.
    fn flush(&mut self) -> io::Result<()> {
        Ok(())
    }
}

/// Reads the whole file at `path`, past the page cache where direct I/O suits (see the
/// module documentation), so that a product read once does not fill the cache.
pub fn read(path: &Path) -> io::Result<Vec<u8>> {
    let mut file = File::open(path)?;
    let size = file.metadata()?.len() as usize;
    let mut out = Vec::with_capacity(size);
    if size < BLOCK || !try_direct(&file) {
        file.read_to_end(&mut out)?;
        return Ok(out);
    }
    let mut buf = Aligned::new();
    let mut direct = true;
    loop {
        let got = match file.read(buf.buf()) {
            Ok(k) => k,
            Err(e) if e.kind() == io::ErrorKind::Interrupted => continue,
            Err(e) if direct && refused(&e) && sys::set_direct(&file, false) => {
                direct = false;
                continue;
            }
            Err(e) => return Err(e),
        };
        if got == 0 {
            break;
        }
        out.extend_from_slice(&buf.buf()[..got]);
        // A short direct read ends at the end of the file or leaves the offset unaligned.
        if direct && got % ALIGN != 0 {
            if !sys::set_direct(&file, false) {
                return Err(io::Error::other("cannot leave direct I/O"));
            }
            direct = false;
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn content(n: usize) -> Vec<u8> {
        (0..n).map(|i| (i * 7 + i / 4096) as u8).collect()
    }

    #[test]
    fn every_length_writes_and_reads_back_the_same_bytes() {
        let dir = tempfile::tempdir().unwrap();
        for (k, &n) in [
            0,
            1,
            ALIGN - 1,
            ALIGN,
            BLOCK - 1,
            BLOCK,
            BLOCK + 1,
            2 * BLOCK + ALIGN + 17,
        ]
        .iter()
        .enumerate()
        {
            let data = content(n);
            for direct in [false, true] {
                let p = dir.path().join(format!("f{k}-{direct}"));
                let file = File::create(&p).unwrap();
                // Where the filesystem allows it, the direct path must really be taken.
                let goes_direct = direct && n >= BLOCK && enabled() && sys::suits(&file);
                let mut w = Writer::with_direct(file, direct);
                // Odd-sized pieces, so blocks fill in the middle of a write.
                for piece in data.chunks(1_000_003) {
                    w.write_all(piece).unwrap();
                }
                assert_eq!(w.is_direct(), goes_direct, "{n} bytes, direct {direct}");
                let f = w.finish().unwrap();
                assert_eq!(f.metadata().unwrap().len(), n as u64, "length {n}");
                drop(f);
                assert!(
                    std::fs::read(&p).unwrap() == data,
                    "{n} bytes, direct {direct}"
                );
                assert!(read(&p).unwrap() == data, "{n} bytes read back");
            }
        }
    }

    #[test]
    fn small_files_never_go_direct() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("small");
        let mut w = Writer::new(File::create(&p).unwrap());
        w.write_all(&content(BLOCK - 1)).unwrap();
        assert!(!w.is_direct());
        w.finish().unwrap();
    }
}
