//! Per-pixel and per-point buffers filled in parallel.
//!
//! A `vec![v; n]` of a map or a scan is written by one thread; under the kept-memory allocator
//! (see [`crate::sys::keep_freed_memory`]) even a zero fill is a serial `memset`, and fresh
//! pages fault in on that thread while the other cores wait for the next parallel stage.

use rayon::prelude::*;

/// `n` copies of `v`, written in parallel.
pub fn filled<T: Clone + Send + Sync>(n: usize, v: T) -> Vec<T> {
    rayon::iter::repeat_n(v, n).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn equals_the_serial_fill() {
        for n in [0usize, 1, 7, 4096, 100_003] {
            assert_eq!(filled(n, 2.5f32), vec![2.5f32; n]);
            assert_eq!(filled(n, u32::MAX), vec![u32::MAX; n]);
        }
    }
}
