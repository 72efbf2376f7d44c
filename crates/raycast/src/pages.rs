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
//! So [`Pages`] allocates arrays of 2 MiB or more at 2 MiB alignment and, on Linux, advises
//! the kernel to back them with transparent huge pages (`madvise(MADV_HUGEPAGE)`), before the
//! first write, so that the pages are huge from the first fault. The advice is a hint: with
//! transparent huge pages off (`/sys/kernel/mm/transparent_hugepage/enabled` = `never`) the
//! memory is ordinary and only the speed differs. The end of an array past its last 2 MiB
//! boundary stays on small pages (rounding the allocation up would cost up to 2 MiB each).

use std::{alloc::Layout, fmt, ops::Deref, ptr::NonNull};

/// The size (and alignment) of a huge page, in bytes.
const HUGE_PAGE: usize = 2 << 20;

/// A fixed-length array of `T`, allocated at huge-page alignment and advised for huge pages
/// when it is at least one huge page long (see the module documentation). Dereferences to
/// `[T]`.
pub(crate) struct Pages<T: Copy> {
    /// The first element (dangling when `len` is 0 or `T` is zero-sized: nothing allocated).
    ptr: NonNull<T>,
    len: usize,
}

impl<T: Copy> Pages<T> {
    /// A copy of `items` in memory of its own.
    pub(crate) fn copy_of(items: &[T]) -> Pages<T> {
        let Some(layout) = Pages::<T>::layout(items.len()) else {
            return Pages {
                ptr: NonNull::dangling(),
                len: items.len(),
            };
        };
        // SAFETY: `layout` has a non-zero size (`layout` returns `None` for empty arrays) and
        // a power-of-two alignment (`Layout::from_size_align` checked it).
        #[allow(unsafe_code)]
        let raw = unsafe { std::alloc::alloc(layout) };
        let Some(ptr) = NonNull::new(raw.cast::<T>()) else {
            std::alloc::handle_alloc_error(layout)
        };
        if layout.align() == HUGE_PAGE {
            advise_huge_pages(raw, layout.size());
        }
        // SAFETY: `ptr` points to a fresh allocation of `items.len()` elements of `T` (the
        // layout's size and an alignment that is a multiple of `T`'s), which cannot overlap
        // `items`; `T: Copy`, so a bitwise copy is a valid value and nothing needs dropping.
        #[allow(unsafe_code)]
        unsafe {
            std::ptr::copy_nonoverlapping(items.as_ptr(), ptr.as_ptr(), items.len());
        }
        Pages {
            ptr,
            len: items.len(),
        }
    }

    /// The allocation of `len` elements: at huge-page alignment from one huge page up, at
    /// `T`'s below; `None` when it is empty (nothing to allocate).
    fn layout(len: usize) -> Option<Layout> {
        let size = size_of::<T>()
            .checked_mul(len)
            .expect("array size overflows");
        if size == 0 {
            return None;
        }
        let align = if size >= HUGE_PAGE {
            HUGE_PAGE.max(align_of::<T>())
        } else {
            align_of::<T>()
        };
        Some(Layout::from_size_align(size, align).expect("a power-of-two alignment"))
    }
}

/// Advises the kernel to back the `size` bytes at `start` (huge-page aligned) with transparent
/// huge pages. A hint: its failure (an old kernel, huge pages off) only costs speed.
#[cfg(target_os = "linux")]
fn advise_huge_pages(start: *mut u8, size: usize) {
    // SAFETY: `madvise` with `MADV_HUGEPAGE` changes no memory contents and no access rights;
    // it only marks the range as preferring huge pages. The range is page aligned (huge-page
    // aligned, in fact) and lies inside an allocation this process owns, so no other mapping is
    // affected. An error return is ignored on purpose: the advice is optional.
    #[allow(unsafe_code)]
    unsafe {
        libc::madvise(start.cast(), size, libc::MADV_HUGEPAGE);
    }
}

/// Elsewhere there is no such advice: the memory is only aligned.
#[cfg(not(target_os = "linux"))]
fn advise_huge_pages(_start: *mut u8, _size: usize) {}

impl<T: Copy> Deref for Pages<T> {
    type Target = [T];

    #[inline(always)]
    fn deref(&self) -> &[T] {
        // SAFETY: `ptr` is non-null and aligned for `T`, and either points to `len` elements
        // initialised by `copy_of` and owned by `self` (immutable from then on, so shared
        // borrows of `self` may read them), or is dangling with nothing allocated because the
        // array takes no bytes, which `from_raw_parts` allows.
        #[allow(unsafe_code)]
        unsafe {
            std::slice::from_raw_parts(self.ptr.as_ptr(), self.len)
        }
    }
}

impl<T: Copy> Drop for Pages<T> {
    fn drop(&mut self) {
        if let Some(layout) = Pages::<T>::layout(self.len) {
            // SAFETY: `ptr` was returned by `alloc` with this very layout (`layout` is a pure
            // function of `len`, which never changes) and is freed only here, once.
            #[allow(unsafe_code)]
            unsafe {
                std::alloc::dealloc(self.ptr.as_ptr().cast(), layout);
            }
        }
    }
}

impl<T: Copy> Clone for Pages<T> {
    fn clone(&self) -> Pages<T> {
        Pages::copy_of(self)
    }
}

impl<T: Copy + fmt::Debug> fmt::Debug for Pages<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_list().entries(self.iter()).finish()
    }
}

// SAFETY: `Pages<T>` owns its elements like a `Box<[T]>` does, and hands out only shared
// borrows of them (there is no mutation after `copy_of`): sending it to another thread sends
// the `T`s, and sharing it shares `&[T]`, which is sound exactly when `T` is `Send` / `Sync`.
#[allow(unsafe_code)]
unsafe impl<T: Copy + Send> Send for Pages<T> {}
// SAFETY: see `Send` above.
#[allow(unsafe_code)]
unsafe impl<T: Copy + Sync> Sync for Pages<T> {}

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
    fn arrays_of_a_huge_page_or_more_start_on_a_huge_page_boundary() {
        let big = Pages::copy_of(&vec![1u8; HUGE_PAGE]);
        assert_eq!(big.as_ptr() as usize % HUGE_PAGE, 0);
        // over-aligned element types keep their own alignment below that
        #[derive(Clone, Copy)]
        #[repr(align(64))]
        struct Line([u8; 64]);
        let small = Pages::copy_of(&[Line([3; 64]); 5]);
        assert_eq!(small.as_ptr() as usize % 64, 0);
        assert!(small.iter().all(|l| l.0 == [3; 64]));
    }

    #[test]
    fn zero_sized_elements_allocate_nothing() {
        let pages = Pages::copy_of(&[(); 10]);
        assert_eq!(pages.len(), 10);
    }
}
