//! Probes of the machine and the process (resident memory, total memory) and the allocator
//! setting the budgeted runs use. No knowledge of scans or stages.

/// A field of a `/proc` status file in bytes (given there in kB), where the system tells.
fn proc_kb(file: &str, field: &str) -> Option<u64> {
    let s = std::fs::read_to_string(file).ok()?;
    let line = s.lines().find(|l| l.starts_with(field))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

/// Peak resident memory of this process so far (bytes), where the system tells.
pub fn peak_rss() -> Option<u64> {
    proc_kb("/proc/self/status", "VmHWM:")
}

/// Resident memory of this process now (bytes), where the system tells.
pub fn current_rss() -> Option<u64> {
    proc_kb("/proc/self/status", "VmRSS:")
}

/// CPU seconds this process has used so far (user + system), from `/proc/self/stat`; 0 where
/// the system does not tell. On a shared machine it is steadier than wall time.
pub fn cpu_seconds() -> f64 {
    let Ok(s) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the parenthesised command name; utime and stime are the 12th and 13th.
    let rest = s.rsplit_once(')').map_or("", |x| x.1);
    let f: Vec<&str> = rest.split_whitespace().collect();
    let tick = |k: usize| f.get(k).and_then(|x| x.parse::<f64>().ok()).unwrap_or(0.0);
    (tick(11) + tick(12)) / 100.0
}

/// Total memory of the machine (bytes), where the system tells.
pub fn total_memory() -> Option<u64> {
    proc_kb("/proc/meminfo", "MemTotal:")
}

/// The default budget: half the machine's memory (4 GiB where it cannot be read).
pub fn default_budget() -> u64 {
    total_memory().map_or(4 << 30, |m| m / 2)
}

/// Lets the allocator keep the memory a run frees for its next allocations.
///
/// A view's maps are tens of megabytes, allocated and freed once per scan. Handed back to the
/// system, each new allocation arrives as fresh pages the kernel must fault in and zero, on
/// one thread while the others wait. Resident memory then includes what the allocator keeps,
/// which the map cache counts as held outside it: an over-estimate, never an under-estimate.
/// The same holds for the few huge-page buffers [`crate::pagebuf`] keeps. One arena for all
/// threads lets a buffer freed by one thread (a product writer) be reused by another.
pub fn keep_freed_memory() {
    KEEP_FREED.store(true, std::sync::atomic::Ordering::Relaxed);
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: mallopt sets three of glibc's allocator parameters (plain integers, under the main
    // arena's lock); an allocation running on another thread meanwhile follows the old value
    // or the new one, both valid.
    unsafe {
        libc::mallopt(libc::M_MMAP_MAX, 0);
        libc::mallopt(libc::M_TRIM_THRESHOLD, i32::MAX);
        libc::mallopt(libc::M_ARENA_MAX, 1);
    }
    crate::pagebuf::keep_freed();
}

/// Whether [`keep_freed_memory`] has been called.
pub fn keeps_freed_memory() -> bool {
    KEEP_FREED.load(std::sync::atomic::Ordering::Relaxed)
}

/// Set once [`keep_freed_memory`] has been called.
static KEEP_FREED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);

/// Hands the memory the allocator holds free back to the system, unless it was asked to keep
/// it ([`keep_freed_memory`]). The map cache measures the resident memory held beside it: the
/// freed buffers of a stage just over (a view's G-buffer, its SSAO passes) would otherwise
/// count as held and leave no room for the views that fit.
pub fn return_freed_memory() {
    if keeps_freed_memory() {
        return;
    }
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    // SAFETY: malloc_trim only releases free pages of glibc's arenas, under their locks.
    unsafe {
        libc::malloc_trim(0);
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_probes_read_plausible_sizes_where_the_system_tells() {
        if let (Some(now), Some(peak), Some(total)) = (
            super::current_rss(),
            super::peak_rss(),
            super::total_memory(),
        ) {
            assert!(now > 0 && now <= peak, "rss {now}, peak {peak}");
            assert!(peak < total, "peak {peak}, total {total}");
            assert_eq!(super::default_budget(), total / 2);
        }
    }
}
