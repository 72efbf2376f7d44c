//! Memory for the finished BVH: a fixed-length array on huge pages where the system has them.
//!
//! A traversal reads nodes and packets all over the hierarchy. With 4 KiB pages a BVH of a
//! million triangles (75 MB) spans 18k pages, far beyond what the processor's address
//! translation cache holds, so most node visits also miss in it and walk the page tables (under
//! a hypervisor, two of them). On 2 MiB pages the same BVH spans 36. Measured on the rooms of
//! the Embree comparison (closest hit, one thread, this crate's `cast` example with and without
//! the advice, alternating, best of 7-9 runs; a Xeon under KVM): 14-16% faster at 100k
//! triangles and 21% faster at 1M. Embree's BVH sits on huge pages too: during its part of the
//! benchmark the process holds 64 MiB of `AnonHugePages`, and none during mcrad's before this.
//!
//! So on Linux [`Pages`] puts arrays of 2 MiB or more in an anonymous memory map of their own
//! (memmap2), from its first 2 MiB boundary on (the map is one huge page longer than the array
//! for that; the part before the boundary is never touched, so it takes no memory), and advises
//! the kernel to back them with transparent huge pages (`madvise(MADV_HUGEPAGE)`) before the
//! first write, so that the pages are huge from the first fault. The advice is a hint: with
//! transparent huge pages off (`/sys/kernel/mm/transparent_hugepage/enabled` = `never`) the
//! memory is ordinary and only the speed differs. The end of an array past its last 2 MiB
//! boundary stays on small pages (rounding the map up would cost up to 2 MiB each). Smaller
//! arrays, and every array elsewhere, are on the heap. The elements are plain data
//! ([`bytemuck::Pod`]), so the map's bytes are viewed as elements without unsafe code.
//!
//! Measured again when the hand-written allocator this replaced was weighed against a plain
//! `Box<[T]>` (issue 33; the `cast` example, one thread, 1e6 rays, medians of 7 interleaved
//! runs on a loaded 2-core KVM guest with transparent huge pages on `madvise`): huge pages
//! were 12.7% faster for closest hit and 9.4% for occlusion in the 1M room, and within the
//! noise (-1% and +2%) in the 100k room. This map against that allocator, the same way: 1M
//! room closest hit -1.7%, occlusion -0.4% (11 runs); 100k room +2.1% and -0.7%: equal within
//! the noise, with the same 48 MiB of `AnonHugePages` in the 1M room.

use bytemuck::Pod;
use std::{
    fmt,
    ops::{Deref, DerefMut},
};

/// The size (and alignment) of a huge page, in bytes.
const HUGE_PAGE: usize = 2 << 20;

/// A fixed-length array of plain-data `T`, on huge pages when it is at least one huge page
/// long and the system has them (see the module documentation). Dereferences to `[T]`.
pub(crate) struct Pages<T: Pod> {
    memory: Memory<T>,
}

/// Where the elements of a [`Pages`] are.
enum Memory<T> {
    /// On the heap.
    Heap(Box<[T]>),
    /// `len` elements from byte `start` (a huge-page boundary) of an anonymous map.
    #[cfg(target_os = "linux")]
    Mapped {
        map: memmap2::MmapMut,
        start: usize,
        len: usize,
    },
}

impl<T: Pod> Pages<T> {
    /// A copy of `items` in memory of its own.
    pub(crate) fn copy_of(items: &[T]) -> Pages<T> {
        let mut pages = Pages::zeroed(items.len());
        pages.copy_from_slice(items);
        pages
    }

    /// `len` all-zero elements, to be written in place. A mapped array takes memory only as
    /// it is written (the system's zero pages until then), so filling it from other arrays
    /// freed one by one needs no second copy of the whole.
    pub(crate) fn zeroed(len: usize) -> Pages<T> {
        #[cfg(target_os = "linux")]
        if let Some(bytes) = len.checked_mul(size_of::<T>())
            && bytes >= HUGE_PAGE
            && let Some((map, start)) = map_huge(bytes)
        {
            return Pages {
                memory: Memory::Mapped { map, start, len },
            };
        }
        Pages {
            memory: Memory::Heap(vec![T::zeroed(); len].into()),
        }
    }
}

/// An anonymous map holding `bytes` zero bytes from the returned offset in it on: its first
/// huge-page boundary, the range advised for huge pages before anything writes it. `None` if
/// the system has no such map to give (the caller falls back on the heap).
#[cfg(target_os = "linux")]
fn map_huge(bytes: usize) -> Option<(memmap2::MmapMut, usize)> {
    let map = memmap2::MmapOptions::new()
        .len(bytes.checked_add(HUGE_PAGE)?)
        .map_anon()
        .ok()?;
    // Maps start on a page boundary, so the first huge-page boundary is within the first
    // HUGE_PAGE bytes.
    let start = map.as_ptr().addr().next_multiple_of(HUGE_PAGE) - map.as_ptr().addr();
    // A hint: its failure (an old kernel, huge pages off) only costs speed.
    let _ = map.advise_range(memmap2::Advice::HugePage, start, bytes);
    Some((map, start))
}

impl<T: Pod> Deref for Pages<T> {
    type Target = [T];

    #[inline(always)]
    fn deref(&self) -> &[T] {
        match &self.memory {
            Memory::Heap(items) => items,
            // The map starts on a page boundary and `start` is a multiple of a huge page, so
            // the bytes are aligned for any `T` of this crate (the cast checks it).
            #[cfg(target_os = "linux")]
            Memory::Mapped { map, start, len } => {
                bytemuck::cast_slice(&map[*start..*start + len * size_of::<T>()])
            }
        }
    }
}

impl<T: Pod> DerefMut for Pages<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        match &mut self.memory {
            Memory::Heap(items) => items,
            // (aligned as in `deref`)
            #[cfg(target_os = "linux")]
            Memory::Mapped { map, start, len } => {
                bytemuck::cast_slice_mut(&mut map[*start..*start + *len * size_of::<T>()])
            }
        }
    }
}

impl<T: Pod> Clone for Pages<T> {
    fn clone(&self) -> Pages<T> {
        Pages::copy_of(self)
    }
}

impl<T: Pod + fmt::Debug> fmt::Debug for Pages<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn copies_keep_every_element_at_any_size() {
        for len in [0usize, 1, 7, 1000, HUGE_PAGE / 8 + 3] {
            let items: Vec<u64> = (0..len as u64).map(|i| i * 2654435761).collect();
            let pages = Pages::copy_of(&items);
            assert_eq!(&pages[..], &items[..]);
            let copy = pages.clone();
            drop(pages);
            assert_eq!(&copy[..], &items[..]);
        }
    }

    #[test]
    #[cfg(target_os = "linux")]
    fn arrays_of_a_huge_page_or_more_start_on_a_huge_page_boundary() {
        let big = Pages::copy_of(&vec![1u8; HUGE_PAGE]);
        assert_eq!(big.as_ptr() as usize % HUGE_PAGE, 0);
        assert!(big.iter().all(|&b| b == 1));
    }

    #[test]
    fn over_aligned_elements_keep_their_alignment() {
        #[derive(Clone, Copy, bytemuck::Pod, bytemuck::Zeroable)]
        #[repr(C, align(64))]
        struct Line([u8; 64]);
        let small = Pages::copy_of(&[Line([3; 64]); 5]);
        assert_eq!(small.as_ptr() as usize % 64, 0);
        assert!(small.iter().all(|l| l.0 == [3; 64]));
        let big = Pages::copy_of(&vec![Line([5; 64]); HUGE_PAGE / 64 + 1]);
        assert_eq!(big.as_ptr() as usize % 64, 0);
        assert!(big.iter().all(|l| l.0 == [5; 64]));
    }

    #[test]
    fn zero_sized_elements_allocate_nothing() {
        let pages = Pages::copy_of(&[(); 10]);
        assert_eq!(pages.len(), 10);
    }
}
