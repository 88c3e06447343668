//! The binary's global allocator: the system's, except that large blocks get their own
//! anonymous mappings advised for 2 MiB pages.
//!
//! A budgeted run that cannot keep what it frees ([`crate::sys::keep_freed_memory`]) hands
//! every large buffer back to the system and gets fresh pages for the next one: a per-point
//! array of an 8 M-point site or a map of a 2048×1024 station is faulted in one 4 KiB page at
//! a time, and on the survey suite the kernel spent about an eighth of the run's CPU time in
//! those faults. Backed by huge pages, the same buffer takes one fault per 2 MiB. While the
//! run keeps freed memory, the system's allocator (which then recycles it without faults)
//! serves every new block.
//!
//! Even on huge pages the kernel zeroes every fresh page, and a run maps several times its
//! peak memory over its scans (each scan allocates the same buffers again): on a virtual
//! machine, where the host may have to back each page anew, that zeroing took a quarter of a
//! survey run's cycles. So a freed mapping is kept and the next large block takes it (its
//! head, the rest staying kept, or the whole grown by the kernel), never adding to what the
//! process would hold without the keeping: a block that grows a kept mapping returns as many
//! bytes of the other kept ones.
//! [`kept_bytes`] tells the memory probes how much of the resident memory is kept this way.

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
/// Serialises changes to [`SLOT`] (lookups read it without the lock) and to the kept
/// mappings.
static LOCK: AtomicBool = AtomicBool::new(false);
/// Freed mappings kept for reuse: start (0: free slot) and mapped bytes, changed under [`LOCK`].
static KEPT_AT: [AtomicUsize; KEPT_SLOTS] = [const { AtomicUsize::new(0) }; KEPT_SLOTS];
static KEPT_LEN: [AtomicUsize; KEPT_SLOTS] = [const { AtomicUsize::new(0) }; KEPT_SLOTS];
/// Freed mappings kept at most.
const KEPT_SLOTS: usize = 64;
/// Bytes of the kept mappings.
static KEPT: AtomicUsize = AtomicUsize::new(0);

/// Resident bytes of the freed mappings kept for the next large blocks: memory the process
/// holds, but free for the run's next buffers. Pages of a kept mapping never touched are not
/// resident and not counted.
pub fn kept_bytes() -> u64 {
    if KEPT.load(Ordering::Relaxed) == 0 {
        return 0;
    }
    let mut kept = [(0usize, 0usize); KEPT_SLOTS];
    lock();
    for (k, e) in kept.iter_mut().enumerate() {
        *e = kept_entry(k);
    }
    unlock();
    // A mapping another thread takes meanwhile may still be counted here: a probe of the
    // moment, like the resident size it is subtracted from.
    kept.iter()
        .filter(|e| e.0 != 0)
        .map(|&(a, l)| os::resident(a, l))
        .sum()
}

/// Returns kept mappings to the system until at most `limit` bytes stay kept: resident
/// memory that only saves the next large blocks their page faults, which a run short of
/// memory cannot afford (the map cache calls it before a load that the budget holds only
/// with fewer of them).
pub fn trim_kept(limit: u64) {
    let kept = KEPT.load(Ordering::Relaxed) as u64;
    if kept <= limit {
        return;
    }
    // Whole huge pages, as every kept length is.
    let surplus = usize::try_from(kept - limit).map_or(usize::MAX, |s| s.div_ceil(HUGE) * HUGE);
    lock();
    let spare = cut_tails(surplus);
    unlock();
    unmap_all(&spare);
}

/// Cuts `surplus` bytes (whole huge pages) from the tails of the kept mappings (under the
/// lock), taking a mapping whole when its tail is not enough: the pieces to unmap.
fn cut_tails(mut surplus: usize) -> [(usize, usize); KEPT_SLOTS] {
    let mut spare = [(0usize, 0usize); KEPT_SLOTS];
    for (j, s) in spare.iter_mut().enumerate() {
        let (a, l) = kept_entry(j);
        if surplus == 0 {
            break;
        }
        if a == 0 {
            continue;
        }
        let cut = surplus.min(l);
        if cut == l {
            *s = take_kept(j);
        } else {
            KEPT_LEN[j].store(l - cut, Ordering::Relaxed);
            KEPT.fetch_sub(cut, Ordering::Relaxed);
            *s = (a + l - cut, cut);
        }
        surplus -= cut;
    }
    spare
}

/// Unmaps the pieces `cut_tails` cut (outside the lock).
fn unmap_all(spare: &[(usize, usize)]) {
    for &(a, l) in spare.iter().filter(|s| s.0 != 0) {
        os::unmap(a as *mut u8, l);
    }
}

/// Keeps the freed mapping at `addr` of `len` mapped bytes, joined to the kept ones it
/// borders (the pieces of one split mapping, freed at different times, become one again);
/// false when the table is full.
fn keep(mut addr: usize, mut len: usize) -> bool {
    lock();
    for k in 0..KEPT_SLOTS {
        let (a, l) = kept_entry(k);
        if a != 0 && (a + l == addr || addr + len == a) {
            take_kept(k);
            (addr, len) = (addr.min(a), len + l);
        }
    }
    let slot = KEPT_AT.iter().position(|s| s.load(Ordering::Relaxed) == 0);
    if let Some(k) = slot {
        KEPT_AT[k].store(addr, Ordering::Relaxed);
        KEPT_LEN[k].store(len, Ordering::Relaxed);
        KEPT.fetch_add(len, Ordering::Relaxed);
    }
    unlock();
    slot.is_some()
}

/// Kept mapping `k` (under the lock): its start (0: none) and mapped bytes.
fn kept_entry(k: usize) -> (usize, usize) {
    (
        KEPT_AT[k].load(Ordering::Relaxed),
        KEPT_LEN[k].load(Ordering::Relaxed),
    )
}

/// Takes kept mapping `k` out of the table (under the lock): its start and mapped bytes.
fn take_kept(k: usize) -> (usize, usize) {
    let (at, len) = kept_entry(k);
    KEPT_AT[k].store(0, Ordering::Relaxed);
    KEPT.fetch_sub(len, Ordering::Relaxed);
    (at, len)
}

/// A kept mapping made into a tracked block of `size` bytes, and how many of its first bytes
/// may not be zero: the head of the smallest kept mapping that holds the block (the rest
/// stays kept), else the largest, grown (and as many bytes of the other kept mappings
/// returned, so that the process holds no more than it would have without them). `None`
/// when none is kept or the system refuses.
fn reuse(size: usize) -> Option<(*mut u8, usize)> {
    let need = mapped_len(size);
    lock();
    let mut pick: Option<(usize, usize)> = None;
    for k in 0..KEPT_SLOTS {
        let (at, len) = kept_entry(k);
        if at == 0 {
            continue;
        }
        let better = pick.is_none_or(|(_, best)| {
            if best >= need {
                len >= need && len < best
            } else {
                len > best
            }
        });
        if better {
            pick = Some((k, len));
        }
    }
    let Some((k, len)) = pick else {
        unlock();
        return None;
    };
    let at = KEPT_AT[k].load(Ordering::Relaxed);
    if len > need {
        // The rest stays kept (a mapping can be unmapped or moved piecewise at page
        // boundaries): a small block does not cost a large one's pages.
        KEPT_AT[k].store(at + need, Ordering::Relaxed);
        KEPT_LEN[k].store(len - need, Ordering::Relaxed);
        KEPT.fetch_sub(need, Ordering::Relaxed);
        unlock();
        if !track(at) {
            os::unmap(at as *mut u8, need);
            return None;
        }
        return Some((at as *mut u8, size));
    }
    take_kept(k);
    // The growth is returned from the tails of the other kept mappings (all lengths are
    // whole huge pages).
    let spare = cut_tails(need.saturating_sub(len));
    unlock();
    unmap_all(&spare);
    let p = if len < need {
        let p = os::remap(at as *mut u8, len, need);
        if p.is_null() {
            // Refused (joined pieces of separate mappings cannot be moved as one).
            if !keep(at, len) {
                os::unmap(at as *mut u8, len);
            }
            return None;
        }
        p
    } else {
        at as *mut u8
    };
    if !track(p as usize) {
        os::unmap(p, need);
        return None;
    }
    Some((p, len.min(size)))
}

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

    /// Resident bytes of the `len` bytes at page-aligned `addr` (0 when it is not mapped).
    pub(super) fn resident(addr: usize, len: usize) -> u64 {
        const PAGE: usize = 4096;
        let mut pages = vec![0u8; len.div_ceil(PAGE)];
        // SAFETY: mincore only reads the page tables of the range and writes one byte per
        // page into `pages`, which holds that many.
        let r = unsafe { libc::mincore(addr as *mut libc::c_void, len, pages.as_mut_ptr()) };
        if r != 0 {
            return 0;
        }
        pages.iter().filter(|&&p| p & 1 != 0).count() as u64 * PAGE as u64
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

    pub(super) fn resident(_addr: usize, _len: usize) -> u64 {
        0
    }
}

impl BigAlloc {
    /// A mapped block for `layout`, and how many of its first bytes are not zero: a kept
    /// mapping when there is one, else a fresh one when the block gets one ([`wanted`]) and
    /// the system grants it.
    fn wanted_map(layout: Layout) -> Option<(*mut u8, usize)> {
        if layout.size() < BIG || layout.align() > 4096 {
            return None;
        }
        if let Some(r) = reuse(layout.size()) {
            return Some(r);
        }
        if !wanted(layout) {
            return None;
        }
        let p = Self::map(layout);
        (!p.is_null()).then_some((p, 0))
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
            Some((p, _)) => p,
            // SAFETY: forwarded with the caller's guarantees.
            None => unsafe { System.alloc(layout) },
        }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        // Fresh pages read as zero: only a kept mapping's used part is filled, and no fresh
        // page is touched before it is used.
        match Self::wanted_map(layout) {
            Some((p, used)) => {
                // SAFETY: the block holds at least `layout.size() ≥ used` writable bytes.
                unsafe { p.write_bytes(0, used) };
                p
            }
            // SAFETY: forwarded with the caller's guarantees.
            None => unsafe { System.alloc_zeroed(layout) },
        }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        if layout.size() >= BIG && untrack(ptr as usize) {
            let len = mapped_len(layout.size());
            if !keep(ptr as usize, len) {
                os::unmap(ptr, len);
            }
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

    /// The tests share the tables: one at a time.
    static SERIAL: std::sync::Mutex<()> = std::sync::Mutex::new(());

    #[test]
    fn large_blocks_are_mapped_zeroed_moved_and_freed() {
        let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
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
        // No block is still tracked (freed mappings may be kept).
        assert!(SLOT.iter().all(|s| s.load(Ordering::Relaxed) == 0));
    }

    #[test]
    fn freed_mappings_are_taken_again_split_or_grown_and_read_zero() {
        let _one = SERIAL.lock().unwrap_or_else(|e| e.into_inner());
        let a = BigAlloc;
        let lay = |n: usize| Layout::from_size_align(n, 64).unwrap();
        unsafe {
            let p = a.alloc(lay(3 * BIG));
            if !SLOT.iter().any(|s| s.load(Ordering::Relaxed) == p as usize) {
                // The run keeps freed memory (set by another test): the system's block.
                a.dealloc(p, lay(3 * BIG));
                return;
            }
            p.write_bytes(9, 3 * BIG);
            a.dealloc(p, lay(3 * BIG));
            assert!(kept_bytes() >= (3 * BIG) as u64);
            // Smaller: the head of a kept mapping, filled with zeros.
            let q = a.alloc_zeroed(lay(BIG + 1));
            assert!(std::slice::from_raw_parts(q, BIG + 1)
                .iter()
                .all(|&b| b == 0));
            q.write_bytes(5, BIG + 1);
            a.dealloc(q, lay(BIG + 1));
            // Larger: grown, old bytes zeroed, new ones zero.
            let r = a.alloc_zeroed(lay(5 * BIG));
            assert!(std::slice::from_raw_parts(r, 5 * BIG)
                .iter()
                .all(|&b| b == 0));
            a.dealloc(r, lay(5 * BIG));
            // Without zeroing, a kept block keeps what it held but is whole and writable.
            let t = a.alloc(lay(4 * BIG));
            t.write_bytes(1, 4 * BIG);
            a.dealloc(t, lay(4 * BIG));
        }
    }
}
