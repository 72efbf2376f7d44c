//! How the process's allocator keeps memory: arrays of 1 MiB or more go back to the system
//! when freed.
//!
//! glibc's malloc serves an array below its mmap threshold from heaps it keeps, and raises the
//! threshold to the size of the largest array freed (up to 32 MiB). A solve makes and frees
//! arrays of tens of MiB phase after phase (the scene's, the BVH build's chunks, a mesh's
//! copies), and the heaps then hold freed memory they cannot give back: on the generated
//! atrium of 1M triangles (`--rays 2e6`) the peak was 338-364 MB for a live peak of about
//! 283 MB. A fixed threshold of 1 MiB maps each larger array on its own and unmaps it when
//! freed (peak 289 MB); the price is the page faults of arrays made again: about 0.3 s of
//! system time in 10 s on the 100k atrium, 0.2 s in 17 s on the Cornell box, 0.8 s in 6 s on
//! the 1M atrium at 2e6 rays. Scenes whose arrays stay below 1 MiB are not affected.

/// The threshold at and above which an allocation is a memory map of its own (bytes).
#[cfg(all(target_os = "linux", target_env = "gnu"))]
const MMAP_THRESHOLD: libc::c_int = 1 << 20;

/// Makes the allocator give freed arrays of [`MMAP_THRESHOLD`] bytes or more back to the
/// system (glibc only; elsewhere nothing changes). Called once, before any thread starts.
pub fn give_back_large_arrays() {
    #[cfg(all(target_os = "linux", target_env = "gnu"))]
    {
        // SAFETY: `mallopt` sets one parameter of glibc's allocator, under the allocator's own
        // lock: it takes two integers, reads and writes no memory of ours, and has no
        // precondition (a parameter or value it does not accept is refused by returning 0,
        // and the allocator then keeps its dynamic threshold).
        #[allow(unsafe_code)]
        let _ = unsafe { libc::mallopt(libc::M_MMAP_THRESHOLD, MMAP_THRESHOLD) };
    }
}
