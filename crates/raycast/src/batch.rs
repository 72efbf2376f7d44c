//! Batched queries in a cache-friendly order.
//!
//! Rays cast one after another from random places of a large scene each walk a different part
//! of the hierarchy, and on a scene whose nodes and triangles do not fit in the caches most of
//! their time goes to cache misses. Rays that start close together and head the same way walk
//! the same nodes. So the closest-hit batch of [`Bvh`](crate::Bvh) visits its rays sorted by
//! the Morton code of the origin (the cell of a `2^16` grid over the scene's bounds), then by
//! direction octant, and writes each answer to its own slot. A query's answer does not depend
//! on the order (same ray, same hit), so the results are those of the one-by-one loop.
//! (Occlusion batches are not sorted: there the sort cost as much as it saved, see `bvh.rs`.)

use glam::Vec3;

/// Batches smaller than this are not reordered (sorting would cost more than it saves).
pub(crate) const MIN_SORTED: usize = 256;

/// BVHs of at most this many bytes (see `Bvh::memory_bytes`) stay in the caches: their batches
/// are not reordered either (measured: sorting halves the throughput on a 32-triangle box and
/// raises it by 20-40% on rooms of 100k and 1M triangles).
pub(crate) const CACHED_BYTES: usize = 2 << 20;

/// Spreads the low 16 bits of `x` so that bit `i` lands on bit `3 * i`.
fn spread(x: u64) -> u64 {
    let mut x = x & 0xffff;
    x = (x | (x << 32)) & 0x0000_ffff_0000_0000_ffff;
    x = (x | (x << 16)) & 0x00ff_0000_ff00_00ff;
    x = (x | (x << 8)) & 0xf00f_00f0_0f00_f00f;
    x = (x | (x << 4)) & 0x30c3_0c30_c30c_30c3;
    (x | (x << 2)) & 0x9249_2492_4924_9249
}

/// The sort key of a query starting at `origin` in direction `dir`, for a scene with bounds
/// `(min, max)`: the 48-bit Morton code of the origin's grid cell, then the 3-bit direction
/// octant. Points outside the bounds (or not finite) are clamped to the grid.
pub(crate) fn key(bounds: (Vec3, Vec3), origin: Vec3, dir: Vec3) -> u64 {
    let (min, max) = bounds;
    let scale = Vec3::splat(65535.0) / (max - min).max(Vec3::splat(f32::MIN_POSITIVE));
    // `as u64` saturates (and maps NaN to 0), so every input gives a cell of the grid
    let cell = ((origin - min) * scale).clamp(Vec3::ZERO, Vec3::splat(65535.0));
    let morton =
        spread(cell.x as u64) | (spread(cell.y as u64) << 1) | (spread(cell.z as u64) << 2);
    let octant =
        (dir.x < 0.0) as u64 | (((dir.y < 0.0) as u64) << 1) | (((dir.z < 0.0) as u64) << 2);
    (morton << 3) | octant
}

/// The indices `0..keys.len()` ordered by key (ties by index, so the order is deterministic).
pub(crate) fn order(keys: impl Iterator<Item = u64>) -> Vec<u32> {
    let mut keyed: Vec<(u64, u32)> = keys.zip(0u32..).collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morton_codes_interleave_the_axes() {
        assert_eq!(spread(0b11), 0b1001);
        assert_eq!(spread(0xffff).count_ones(), 16);
        let b = (Vec3::ZERO, Vec3::ONE);
        assert!(key(b, Vec3::ZERO, Vec3::X) < key(b, Vec3::ONE, Vec3::X));
        assert_eq!(key(b, Vec3::ZERO, Vec3::X) & 7, 0);
        assert_eq!(key(b, Vec3::ZERO, -Vec3::ONE) & 7, 7);
        // outside and non-finite points still get a cell
        assert_eq!(key(b, Vec3::splat(-5.0), Vec3::X), 0);
        assert_eq!(key(b, Vec3::splat(f32::NAN), Vec3::X), 0);
    }

    #[test]
    fn order_is_a_stable_permutation() {
        assert_eq!(order([5, 1, 5, 0].into_iter()), vec![3, 1, 0, 2]);
    }
}
