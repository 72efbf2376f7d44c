//! Sample positions inside a pixel: a pure function of (pixel, sample), so a render does not
//! depend on threads or scheduling.

use glam::Vec2;

/// Offset of sample `s` of `n` inside pixel `(x, y)`, in pixel units within `[0, 1)²`.
///
/// One sample goes through the pixel centre. A square count `n = m²` is stratified: sample `s`
/// lies in cell `(s mod m, s div m)` of an `m × m` grid, jittered uniformly within it. Any other
/// count jitters each sample uniformly over the whole pixel.
pub(crate) fn sample_offset(x: u32, y: u32, s: u32, n: u32) -> Vec2 {
    if n <= 1 {
        return Vec2::splat(0.5);
    }
    let u = Vec2::new(unit(hash(x, y, s, 0)), unit(hash(x, y, s, 1)));
    let m = n.isqrt();
    if m * m == n {
        (Vec2::new((s % m) as f32, (s / m) as f32) + u) / m as f32
    } else {
        u
    }
}

/// A well-mixed 32-bit hash of four integers (the splitmix64 finaliser over a packed key).
fn hash(x: u32, y: u32, s: u32, dim: u32) -> u32 {
    let mut z = (u64::from(x) | (u64::from(y) << 32)) ^ 0x9e37_79b9_7f4a_7c15;
    z = mix(z);
    z ^= (u64::from(s) << 8) | u64::from(dim);
    (mix(z) >> 32) as u32
}

/// The splitmix64 output function.
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The top 24 bits of `h` as a float in `[0, 1)`.
fn unit(h: u32) -> f32 {
    (h >> 8) as f32 * (1.0 / (1u32 << 24) as f32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn square_counts_put_one_sample_in_each_stratum() {
        for n in [4u32, 9, 16] {
            let m = n.isqrt();
            let mut seen = vec![false; n as usize];
            for s in 0..n {
                let o = sample_offset(7, 3, s, n);
                assert!(o.cmpge(Vec2::ZERO).all() && o.cmplt(Vec2::ONE).all(), "{o}");
                let cell = (o * m as f32).floor();
                seen[(cell.y as u32 * m + cell.x as u32) as usize] = true;
            }
            assert!(seen.iter().all(|&b| b), "n = {n}");
        }
    }

    #[test]
    fn offsets_are_a_pure_function_and_vary() {
        assert_eq!(sample_offset(1, 2, 3, 5), sample_offset(1, 2, 3, 5));
        assert_ne!(sample_offset(1, 2, 3, 5), sample_offset(2, 1, 3, 5));
        assert_eq!(sample_offset(9, 9, 0, 1), Vec2::splat(0.5));
    }
}
