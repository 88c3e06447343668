//! Buffers for maps read at scattered pixels, backed by 2 MiB pages where the system allows.
//!
//! The horizon SSAO marches eight half-lines from every pixel to pixels tens of rows away:
//! on a 1440-pixel-wide map of 16-byte positions each row is six 4 KiB pages, so a block of
//! pixels reads from hundreds of pages, more than a first-level TLB holds. A [`PageBuf`] is its own
//! anonymous mapping with `MADV_HUGEPAGE`, so it gets fresh pages the kernel can back with
//! huge ones (memory the allocator recycles was already faulted in with small pages and would
//! stay so), and a miss in the TLB then covers 2 MiB instead of 4 KiB.
//!
//! Fresh pages cost the kernel a fault and a clear each; once [`keep_freed`] is called, a
//! dropped buffer's mapping is kept (up to [`POOL_MAPPINGS`]) for the next buffer it can hold.

use bytemuck::Zeroable;
use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;

/// Dropped mappings kept for reuse at most (each one map of one scan).
pub const POOL_MAPPINGS: usize = 2;

/// Whether dropped mappings are kept ([`keep_freed`]).
static KEEP: AtomicBool = AtomicBool::new(false);

/// Kept mappings: (address, bytes).
static POOL: Mutex<Vec<(usize, usize)>> = Mutex::new(Vec::new());

/// From now on, keep dropped mappings for the next buffers instead of returning them to the
/// system (the memory probes decide when that fits).
pub fn keep_freed() {
    KEEP.store(true, Ordering::Relaxed);
}

/// A kept mapping of at least `bytes` and at most twice that, zeroed, if there is one.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
fn reuse(bytes: usize) -> Option<(std::ptr::NonNull<u8>, usize)> {
    let mut pool = POOL.lock().ok()?;
    let k = pool
        .iter()
        .position(|&(_, b)| b >= bytes && b / 2 <= bytes)?;
    let (addr, b) = pool.swap_remove(k);
    let ptr = std::ptr::NonNull::new(addr as *mut u8)?;
    // SAFETY: the pool owns this mapping of `b ≥ bytes` writable bytes.
    unsafe { std::ptr::write_bytes(ptr.as_ptr(), 0, bytes) };
    Some((ptr, b))
}

/// A fixed-length, zero-initialised buffer of plain values (see the module docs).
pub struct PageBuf<T: Zeroable + Copy> {
    mem: Backing<T>,
}

enum Backing<T> {
    /// An anonymous mapping of `bytes` bytes holding `len` values.
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    Mapped {
        ptr: std::ptr::NonNull<T>,
        len: usize,
        bytes: usize,
    },
    /// The allocator's memory: small buffers, other systems, or a refused mapping.
    Heap(Vec<T>),
}

// SAFETY: a PageBuf owns its values exclusively, like a Vec.
unsafe impl<T: Zeroable + Copy + Send> Send for PageBuf<T> {}
// SAFETY: shared access only hands out `&[T]`.
unsafe impl<T: Zeroable + Copy + Sync> Sync for PageBuf<T> {}

/// Below this a buffer cannot hold one aligned huge page worth having.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const MIN_MAPPED: usize = 4 << 20;

impl<T: Zeroable + Copy> PageBuf<T> {
    /// `len` zero values.
    pub fn zeroed(len: usize) -> PageBuf<T> {
        #[cfg(all(target_os = "linux", target_env = "gnu"))]
        if let Some(bytes) = len
            .checked_mul(std::mem::size_of::<T>())
            .filter(|&b| b >= MIN_MAPPED && std::mem::align_of::<T>() <= 4096)
        {
            if let Some((ptr, bytes)) = reuse(bytes) {
                return PageBuf {
                    mem: Backing::Mapped {
                        ptr: ptr.cast(),
                        len,
                        bytes,
                    },
                };
            }
            // SAFETY: a fresh private anonymous mapping (zero-filled by the kernel, page
            // aligned, so aligned for T); MADV_HUGEPAGE changes only how it is backed.
            unsafe {
                let p = libc::mmap(
                    std::ptr::null_mut(),
                    bytes,
                    libc::PROT_READ | libc::PROT_WRITE,
                    libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
                    -1,
                    0,
                );
                if p != libc::MAP_FAILED {
                    libc::madvise(p, bytes, libc::MADV_HUGEPAGE);
                    if let Some(ptr) = std::ptr::NonNull::new(p.cast::<T>()) {
                        return PageBuf {
                            mem: Backing::Mapped { ptr, len, bytes },
                        };
                    }
                }
            }
        }
        PageBuf {
            mem: Backing::Heap(vec![T::zeroed(); len]),
        }
    }

    /// A buffer holding `values`.
    pub fn from_slice(values: &[T]) -> PageBuf<T> {
        let mut b = PageBuf::zeroed(values.len());
        b.copy_from_slice(values);
        b
    }
}

impl<T: Zeroable + Copy> Deref for PageBuf<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        match &self.mem {
            #[cfg(all(target_os = "linux", target_env = "gnu"))]
            // SAFETY: the mapping holds `len` initialised (zeroed or written) values.
            Backing::Mapped { ptr, len, .. } => unsafe {
                std::slice::from_raw_parts(ptr.as_ptr(), *len)
            },
            Backing::Heap(v) => v,
        }
    }
}

impl<T: Zeroable + Copy> DerefMut for PageBuf<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        match &mut self.mem {
            #[cfg(all(target_os = "linux", target_env = "gnu"))]
            // SAFETY: as in deref, and `&mut self` makes the access exclusive.
            Backing::Mapped { ptr, len, .. } => unsafe {
                std::slice::from_raw_parts_mut(ptr.as_ptr(), *len)
            },
            Backing::Heap(v) => v,
        }
    }
}

impl<T: Zeroable + Copy> Drop for PageBuf<T> {
    fn drop(&mut self) {
        #[cfg(all(target_os = "linux", target_env = "gnu"))]
        if let Backing::Mapped { ptr, bytes, .. } = self.mem {
            if KEEP.load(Ordering::Relaxed) {
                if let Ok(mut pool) = POOL.lock() {
                    if pool.len() < POOL_MAPPINGS {
                        pool.push((ptr.as_ptr() as usize, bytes));
                        return;
                    }
                }
            }
            // SAFETY: the mapping was made in `zeroed` with this length and is unmapped once
            // (a kept one is owned by the pool instead).
            unsafe {
                libc::munmap(ptr.as_ptr().cast(), bytes);
            }
        }
    }
}

impl<T: Zeroable + Copy> Clone for PageBuf<T> {
    fn clone(&self) -> Self {
        PageBuf::from_slice(self)
    }
}

impl<T: Zeroable + Copy> Default for PageBuf<T> {
    fn default() -> Self {
        PageBuf::zeroed(0)
    }
}

impl<T: Zeroable + Copy + std::fmt::Debug> std::fmt::Debug for PageBuf<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PageBuf").field("len", &self.len()).finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn a_kept_mapping_comes_back_zeroed() {
        keep_freed();
        let n = 2 << 20;
        let mut a = PageBuf::<f32>::zeroed(n);
        a.iter_mut().for_each(|v| *v = 7.0);
        drop(a);
        let b = PageBuf::<f32>::zeroed(n - 100);
        assert!(b.iter().all(|&v| v == 0.0));
        assert_eq!(b.len(), n - 100);
    }

    #[test]
    fn small_and_large_buffers_hold_what_is_written() {
        for n in [0usize, 1, 1000, 3 << 20] {
            let mut b = PageBuf::<[f32; 3]>::zeroed(n);
            assert_eq!(b.len(), n);
            assert!(b.iter().all(|v| *v == [0.0; 3]));
            b.par_iter_mut()
                .enumerate()
                .for_each(|(i, v)| *v = [i as f32, 1.0, -2.0]);
            let c = b.clone();
            drop(b);
            assert_eq!(c.len(), n);
            assert!(c
                .iter()
                .enumerate()
                .all(|(i, v)| *v == [i as f32, 1.0, -2.0]));
        }
    }
}
