//! Arrays that rays read at random, in memory the kernel is asked to back with huge pages.
//!
//! A million-triangle mesh's wide-BVH nodes and triangle groups take tens of megabytes, read
//! in an order no hardware prefetcher can follow. With 4 KiB pages the TLB covers a few
//! megabytes of that, so most node and group loads also wait for a page walk; with 2 MiB pages
//! a few dozen entries cover it all. On Linux an array of at least [`HUGE_BYTES`] therefore
//! goes in an anonymous mapping advised `MADV_HUGEPAGE` (transparent huge pages), which the
//! kernel honours where THP is `always` or `madvise` (the usual default). Smaller arrays,
//! other systems, and a refused mapping or advice keep an ordinary `Vec`. The contents are the
//! same either way, and so are the rendered bits; docs/renderer.md has the measured gain.

use bytemuck::Pod;

/// Arrays of at least this many bytes (one huge page) are mapped; a smaller one could not
/// fill a huge page anyway.
pub const HUGE_BYTES: usize = 2 << 20;

/// A read-only array of `T`, possibly in huge pages (see the module's docs). Read it through
/// [`PagedArray::as_slice`], once per query: the slice of a mapping is checked as it is made.
pub struct PagedArray<T> {
    vec: Vec<T>,
    #[cfg(target_os = "linux")]
    map: Option<memmap2::MmapMut>,
}

impl<T: Pod> PagedArray<T> {
    /// Takes `items`, moving them into huge pages where that applies.
    pub fn new(items: Vec<T>) -> Self {
        #[cfg(target_os = "linux")]
        if let Some(map) = huge_copy(&items) {
            return Self {
                vec: Vec::new(),
                map: Some(map),
            };
        }
        Self {
            vec: items,
            #[cfg(target_os = "linux")]
            map: None,
        }
    }

    /// The items.
    #[inline]
    pub fn as_slice(&self) -> &[T] {
        #[cfg(target_os = "linux")]
        if let Some(map) = &self.map {
            // A mapping starts on a page boundary, and it was made the items' exact size.
            return bytemuck::cast_slice(&map[..]);
        }
        &self.vec
    }

    /// Whether the items are in a mapping advised for huge pages (for tests).
    pub fn is_mapped(&self) -> bool {
        #[cfg(target_os = "linux")]
        return self.map.is_some();
        #[cfg(not(target_os = "linux"))]
        false
    }
}

/// A copy of `items` in an anonymous mapping advised for huge pages before its first write (so
/// the page faults that fill it can take huge pages at once), or `None` where the array is
/// small or the system refuses.
#[cfg(target_os = "linux")]
fn huge_copy<T: Pod>(items: &[T]) -> Option<memmap2::MmapMut> {
    let bytes: &[u8] = bytemuck::cast_slice(items);
    if bytes.len() < HUGE_BYTES {
        return None;
    }
    let mut map = memmap2::MmapMut::map_anon(bytes.len()).ok()?;
    map.advise(memmap2::Advice::HugePage).ok()?;
    map.copy_from_slice(bytes);
    Some(map)
}

impl<T: Pod> Clone for PagedArray<T> {
    fn clone(&self) -> Self {
        Self::new(self.as_slice().to_vec())
    }
}

impl<T> Default for PagedArray<T> {
    fn default() -> Self {
        Self {
            vec: Vec::new(),
            #[cfg(target_os = "linux")]
            map: None,
        }
    }
}

impl<T: Pod> std::fmt::Debug for PagedArray<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("PagedArray")
            .field("len", &self.as_slice().len())
            .field("mapped", &self.is_mapped())
            .finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Small arrays stay vectors; large ones (on Linux) are mapped; both read back as given,
    /// and so do their clones.
    #[test]
    fn arrays_read_back_what_they_were_given() {
        for n in [0usize, 1, 1000, HUGE_BYTES / 4 + 7] {
            let items: Vec<u32> = (0..n as u32)
                .map(|i| i.wrapping_mul(2_654_435_761))
                .collect();
            let a = PagedArray::new(items.clone());
            assert_eq!(a.as_slice(), &items[..]);
            assert_eq!(a.clone().as_slice(), &items[..]);
            if n * 4 < HUGE_BYTES {
                assert!(!a.is_mapped(), "{n}");
            } else if std::path::Path::new("/sys/kernel/mm/transparent_hugepage").exists() {
                // A kernel with transparent huge pages accepts the advice.
                assert!(a.is_mapped(), "{n}");
            }
        }
    }
}
