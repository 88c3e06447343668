//! The binary's global allocator: the system's, except that large blocks get their own
//! anonymous mappings advised for 2 MiB pages.
//!
//! A budgeted run that cannot keep what it frees ([`crate::sys::keep_freed_memory`]) hands
//! every large buffer back to the system and gets fresh pages for the next one: a per-point
//! array of an 8 M-point site or a map of a 2048×1024 station is faulted in one 4 KiB page at
//! a time, and on the survey suite the kernel spent about an eighth of the run's CPU time in
//! those faults. Backed by huge pages, the same buffer takes one fault per 2 MiB. While the
//! run keeps freed memory, the system's allocator (which then recycles it without faults)
//! serves every block.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};

/// Smallest block given its own mapping.
const BIG: usize = 4 << 20;
/// Huge page size.
const HUGE: usize = 2 << 20;
/// Mappings tracked at once; a block that finds the table full comes from the system.
const SLOTS: usize = 1024;

/// The allocator (see the module docs).
pub struct BigAlloc;

/// Start addresses of the live mappings (0: free slot). A block is ours exactly when its
/// address is here, so a block the system allocated is always returned to the system.
static SLOT: [AtomicUsize; SLOTS] = [const { AtomicUsize::new(0) }; SLOTS];
/// Serialises changes to [`SLOT`] (lookups read it without the lock).
static LOCK: AtomicBool = AtomicBool::new(false);

fn lock() {
    while LOCK
        .compare_exchange_weak(false, true, Ordering::Acquire, Ordering::Relaxed)
        .is_err()
    {
        std::hint::spin_loop();
    }
}

fn unlock() {
    LOCK.store(false, Ordering::Release);
}

/// Records `addr` in a free slot; false when the table is full.
fn track(addr: usize) -> bool {
    lock();
    let slot = SLOT.iter().find(|s| s.load(Ordering::Relaxed) == 0);
    if let Some(s) = slot {
        s.store(addr, Ordering::Relaxed);
    }
    unlock();
    slot.is_some()
}

/// Removes `addr` from the table; false when it was not there (a block of the system's).
fn untrack(addr: usize) -> bool {
    lock();
    let slot = SLOT.iter().find(|s| s.load(Ordering::Relaxed) == addr);
    if let Some(s) = slot {
        s.store(0, Ordering::Relaxed);
    }
    unlock();
    slot.is_some()
}

/// Moves the entry of `old` to `new` (a block that moved keeps its slot).
fn retrack(old: usize, new: usize) {
    lock();
    if let Some(s) = SLOT.iter().find(|s| s.load(Ordering::Relaxed) == old) {
        s.store(new, Ordering::Relaxed);
    }
    unlock();
}

/// Bytes mapped for a block of `size` bytes.
fn mapped_len(size: usize) -> usize {
    size.div_ceil(HUGE) * HUGE
}

/// Whether a block of this layout gets its own mapping now.
fn wanted(layout: Layout) -> bool {
    layout.size() >= BIG && layout.align() <= 4096 && !crate::sys::keeps_freed_memory()
}

#[cfg(target_os = "linux")]
mod os {
    use super::{mapped_len, HUGE};

    /// A zeroed anonymous mapping for `size` bytes, 2 MiB aligned and advised for huge
    /// pages; null when the system refuses.
    pub(super) fn map(size: usize) -> *mut u8 {
        let len = mapped_len(size);
        let Some(over) = len.checked_add(HUGE) else {
            return std::ptr::null_mut();
        };
        // SAFETY: a fresh private anonymous mapping; no existing memory is touched.
        let raw = unsafe {
            libc::mmap(
                std::ptr::null_mut(),
                over,
                libc::PROT_READ | libc::PROT_WRITE,
                libc::MAP_PRIVATE | libc::MAP_ANONYMOUS,
                -1,
                0,
            )
        };
        if raw == libc::MAP_FAILED {
            return std::ptr::null_mut();
        }
        // Trim the over-allocation so that the block starts on a huge-page boundary (a
        // huge page can only back an aligned 2 MiB range of the mapping).
        let start = raw as usize;
        let aligned = start.next_multiple_of(HUGE);
        let (head, tail) = (aligned - start, over - (aligned - start) - len);
        // SAFETY: both ranges lie within the mapping just made and outside the block kept.
        unsafe {
            if head > 0 {
                libc::munmap(raw, head);
            }
            if tail > 0 {
                libc::munmap((aligned + len) as *mut libc::c_void, tail);
            }
            libc::madvise(aligned as *mut libc::c_void, len, libc::MADV_HUGEPAGE);
        }
        aligned as *mut u8
    }

    /// Moves a mapped block of `old` bytes to one of `new` bytes (contents kept, the rest
    /// zero); null when the system refuses (the block is then unchanged).
    pub(super) fn remap(ptr: *mut u8, old: usize, new: usize) -> *mut u8 {
        // SAFETY: `ptr` is the start of a live mapping of `mapped_len(old)` bytes; the kernel
        // either moves it whole or leaves it as it was.
        let p = unsafe {
            libc::mremap(
                ptr.cast(),
                mapped_len(old),
                mapped_len(new),
                libc::MREMAP_MAYMOVE,
            )
        };
        if p == libc::MAP_FAILED {
            return std::ptr::null_mut();
        }
        // SAFETY: `p` is the start of the moved mapping of `mapped_len(new)` bytes.
        unsafe { libc::madvise(p, mapped_len(new), libc::MADV_HUGEPAGE) };
        p.cast()
    }

    /// Unmaps a block [`map`] made for `size` bytes.
    pub(super) fn unmap(ptr: *mut u8, size: usize) {
        // SAFETY: `ptr` is the start of a live mapping of `mapped_len(size)` bytes.
        unsafe { libc::munmap(ptr.cast(), mapped_len(size)) };
    }
}

#[cfg(not(target_os = "linux"))]
mod os {
    pub(super) fn map(_size: usize) -> *mut u8 {
        std::ptr::null_mut()
    }

    pub(super) fn remap(_ptr: *mut u8, _old: usize, _new: usize) -> *mut u8 {
        std::ptr::null_mut()
    }

    pub(super) fn unmap(_ptr: *mut u8, _size: usize) {}
}

impl BigAlloc {
    /// A mapped block for `layout` when it gets one ([`wanted`]) and the system grants it.
    fn wanted_map(layout: Layout) -> Option<*mut u8> {
        if !wanted(layout) {
            return None;
        }
        let p = Self::map(layout);
        (!p.is_null()).then_some(p)
    }

    /// A mapped block for `layout`, tracked; null when it cannot be had (the caller then asks
    /// the system).
    fn map(layout: Layout) -> *mut u8 {
        let p = os::map(layout.size());
        if !p.is_null() && !track(p as usize) {
            os::unmap(p, layout.size());
            return std::ptr::null_mut();
        }
        p
    }
}

// SAFETY: every block is either the system allocator's (allocated, reallocated and freed by
// it) or a tracked mapping of at least its size, 2 MiB aligned (beyond every alignment
// accepted), zeroed when made and unmapped exactly once when freed.
unsafe impl GlobalAlloc for BigAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        match Self::wanted_map(layout) {
            Some(p) => p,
            // SAFETY: forwarded with the caller's guarantees.
            None => unsafe { System.alloc(layout) },
        }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // Fresh mappings read as zero: no fill, and no page touched before it is used.
        match Self::wanted_map(layout) {
            Some(p) => p,
            // SAFETY: forwarded with the caller's guarantees.
            None => unsafe { System.alloc_zeroed(layout) },
        }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if layout.size() >= BIG && untrack(ptr as usize) {
            os::unmap(ptr, layout.size());
            return;
        }
        // SAFETY: not a mapping of ours, so the system allocated it.
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        let ours = layout.size() >= BIG
            && SLOT
                .iter()
                .any(|s| s.load(Ordering::Relaxed) == ptr as usize);
        // SAFETY: `new_size` and the alignment form a valid layout (the caller's guarantee).
        let new = unsafe { Layout::from_size_align_unchecked(new_size, layout.align()) };
        if !ours && !wanted(new) {
            // SAFETY: forwarded with the caller's guarantees.
            return unsafe { System.realloc(ptr, layout, new_size) };
        }
        if ours && new_size >= BIG {
            if mapped_len(new_size) == mapped_len(layout.size()) {
                return ptr;
            }
            // The kernel moves the pages instead of copying them.
            let p = os::remap(ptr, layout.size(), new_size);
            if !p.is_null() {
                retrack(ptr as usize, p as usize);
                return p;
            }
        }
        // SAFETY: `new` is a valid non-zero layout.
        let p = unsafe { self.alloc(new) };
        if !p.is_null() {
            // SAFETY: both blocks are live, distinct and at least this long.
            unsafe { std::ptr::copy_nonoverlapping(ptr, p, layout.size().min(new_size)) };
            // SAFETY: `ptr` was allocated with `layout` and is no longer used.
            unsafe { self.dealloc(ptr, layout) };
        }
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn large_blocks_are_mapped_zeroed_moved_and_freed() {
        let a = BigAlloc;
        let big = Layout::from_size_align(BIG + 12_345, 64).unwrap();
        unsafe {
            let p = a.alloc_zeroed(big);
            assert!(!p.is_null());
            // Another test of the process may have set the run to keep freed memory, and
            // the block is then the system's.
            if SLOT.iter().any(|s| s.load(Ordering::Relaxed) == p as usize) {
                assert_eq!(p as usize % HUGE, 0, "mapped blocks start on a huge page");
            }
            let s = std::slice::from_raw_parts_mut(p, big.size());
            assert!(s.iter().all(|&b| b == 0));
            for (i, b) in s.iter_mut().enumerate() {
                *b = (i % 251) as u8;
            }
            // Grown past its mapping, then shrunk below the threshold: contents kept.
            let q = a.realloc(p, big, 3 * BIG);
            assert!(!q.is_null());
            let s = std::slice::from_raw_parts(q, big.size());
            assert!(s.iter().enumerate().all(|(i, &b)| b == (i % 251) as u8));
            let grown = Layout::from_size_align(3 * BIG, 64).unwrap();
            let r = a.realloc(q, grown, 1000);
            assert!(!r.is_null());
            let s = std::slice::from_raw_parts(r, 1000);
            assert!(s.iter().enumerate().all(|(i, &b)| b == (i % 251) as u8));
            a.dealloc(r, Layout::from_size_align(1000, 64).unwrap());
            // A small block grown past the threshold.
            let small = Layout::from_size_align(100, 8).unwrap();
            let p = a.alloc(small);
            p.write_bytes(7, 100);
            let q = a.realloc(p, small, 2 * BIG);
            assert_eq!(std::slice::from_raw_parts(q, 100), &[7u8; 100][..]);
            a.dealloc(q, Layout::from_size_align(2 * BIG, 8).unwrap());
        }
        // Every mapping was released.
        assert!(SLOT.iter().all(|s| s.load(Ordering::Relaxed) == 0));
    }
}
