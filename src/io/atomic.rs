//! Atomic file output: write to a hidden temporary file beside the target, flush, then rename,
//! so an interrupted run never leaves a file that looks complete.

use super::direct::Writer;
use crate::error::{Error, Result};
use std::fs::File;
use std::path::{Path, PathBuf};

/// Writes `path` atomically: `fill` writes the content into a buffered temporary file in the
/// same directory (large files past the page cache, see [`super::direct`]), which is synced
/// and renamed over `path` only when `fill` succeeds.
pub fn write_atomic<F>(path: &Path, fill: F) -> Result<()>
where
    F: FnOnce(&mut Writer) -> std::io::Result<()>,
{
    write_atomic_with(path, true, fill)
}

/// [`write_atomic`], syncing the content to disk before the rename only when `sync`. Skipping
/// the sync is for files whose readers verify a checksum recorded elsewhere (work-directory
/// products): after a power loss such a file may be empty or torn, which the reader detects,
/// whereas a kill of the process alone never loses what was written.
pub fn write_atomic_with<F>(path: &Path, sync: bool, fill: F) -> Result<()>
where
    F: FnOnce(&mut Writer) -> std::io::Result<()>,
{
    let tmp = temp_path(path);
    let res = (|| {
        let mut w = Writer::new(File::create(&tmp)?);
        fill(&mut w)?;
        let file = w.finish()?;
        if sync {
            file.sync_all()?;
        }
        Ok(())
    })();
    finish(&tmp, path, res.map_err(|e| Error::io(path, e)))
}

/// Renames the written temporary file `tmp` over `path`, or removes it when writing failed.
fn finish(tmp: &Path, path: &Path, written: Result<()>) -> Result<()> {
    match written {
        Ok(()) => std::fs::rename(tmp, path).map_err(|e| {
            let _ = std::fs::remove_file(tmp);
            Error::io(path, e)
        }),
        Err(e) => {
            let _ = std::fs::remove_file(tmp);
            Err(e)
        }
    }
}

/// Writes `path` atomically through the temporary [`File`] itself, for formats that seek back
/// to complete a header after the data (LAS/LAZ). `fill` gets the open temporary file and hands
/// it back when done; it is then synced and renamed over `path`. On error the temporary file is
/// removed and `fill`'s error is returned unchanged, so it should already name `path`.
pub fn write_atomic_file<F>(path: &Path, fill: F) -> Result<()>
where
    F: FnOnce(File) -> Result<File>,
{
    let tmp = temp_path(path);
    // Readable too: LAS writers read header fields back while completing them.
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(true)
        .open(&tmp)
        .map_err(|e| Error::io(path, e))?;
    let res = fill(file).and_then(|file| file.sync_all().map_err(|e| Error::io(path, e)));
    finish(&tmp, path, res)
}

/// Like [`write_atomic`], for writers that seek and read back what they wrote (E57 pages):
/// `fill` gets the temporary file itself, opened for reading and writing.
pub fn write_atomic_seekable<F>(path: &Path, fill: F) -> Result<()>
where
    F: FnOnce(&mut File) -> std::io::Result<()>,
{
    write_atomic_file(path, |mut f| {
        fill(&mut f).map_err(|e| Error::io(path, e))?;
        Ok(f)
    })
}

/// The temporary name used while `path` is being written (`.name.tmp-<pid>` beside it).
pub fn temp_path(path: &Path) -> PathBuf {
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "out".into());
    path.with_file_name(format!(".{name}.tmp-{}", std::process::id()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    #[test]
    fn failed_write_leaves_nothing() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.bin");
        let r = write_atomic(&p, |w| {
            w.write_all(b"partial")?;
            Err(std::io::Error::other("boom"))
        });
        assert!(r.is_err());
        assert!(!p.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 0);
    }

    #[test]
    fn seekable_write_reads_back_and_fails_cleanly() {
        use std::io::{Read, Seek, SeekFrom};
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.e57");
        write_atomic_seekable(&p, |f| {
            f.write_all(b"abcdef")?;
            f.seek(SeekFrom::Start(2))?;
            let mut b = [0u8; 2];
            f.read_exact(&mut b)?;
            f.seek(SeekFrom::End(0))?;
            f.write_all(&b)
        })
        .unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"abcdefcd");
        let q = dir.path().join("y.e57");
        assert!(write_atomic_seekable(&q, |_| Err(std::io::Error::other("boom"))).is_err());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn seekable_write_patches_and_cleans_up() {
        use std::io::{Seek, SeekFrom};
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.bin");
        write_atomic_file(&p, |mut f| {
            f.write_all(b"hello").map_err(|e| Error::io(&p, e))?;
            f.seek(SeekFrom::Start(0)).map_err(|e| Error::io(&p, e))?;
            f.write_all(b"J").map_err(|e| Error::io(&p, e))?;
            Ok(f)
        })
        .unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"Jello");
        let q = dir.path().join("y.bin");
        let r = write_atomic_file(&q, |mut f| {
            f.write_all(b"partial").unwrap();
            Err(Error::Param("boom".into()))
        });
        assert!(matches!(r, Err(Error::Param(_))));
        assert!(!q.exists());
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }

    #[test]
    fn successful_write_renames() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.bin");
        write_atomic(&p, |w| w.write_all(b"hello")).unwrap();
        assert_eq!(std::fs::read(&p).unwrap(), b"hello");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1);
    }
}
