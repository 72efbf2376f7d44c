//! The triangle record the fast caster intersects: one 64-byte cache line per triangle.

use glam::{Vec3A, Vec4};
use obvhs::rt_triangle::RtTriangle;

/// A canonical-frame triangle in the layout of obvhs's [`RtTriangle`] (`v0`, `e1 = v0 - v1`,
/// `e2 = v2 - v0`, `ng = e1 x e2`, so `ng` is minus the counter-clockwise normal), with the
/// caller's id in the spare lane of `v0`: the test and the id check touch one cache line, and
/// no separate id array is read during traversal. Aligned to 64 bytes so that no record
/// straddles two lines.
#[derive(Clone, Copy, Debug)]
#[repr(C, align(64))]
pub(crate) struct Tri {
    /// `v0` in x, y, z; the id's bits in w.
    v0_id: Vec4,
    e1: Vec4,
    e2: Vec4,
    ng: Vec4,
}

impl Tri {
    /// The record of `rt` tagged with `id`.
    pub(crate) fn new(rt: &RtTriangle, id: u32) -> Tri {
        Tri {
            v0_id: rt.v0.extend(f32::from_bits(id)),
            e1: rt.e1.extend(0.0),
            e2: rt.e2.extend(0.0),
            ng: rt.ng.extend(0.0),
        }
    }

    /// The caller's id (bits copied, never computed with, so any `u32` round-trips).
    #[inline(always)]
    pub(crate) fn id(&self) -> u32 {
        self.v0_id.w.to_bits()
    }

    /// First vertex.
    #[inline(always)]
    pub(crate) fn v0(&self) -> Vec3A {
        Vec3A::from_vec4(self.v0_id)
    }

    /// `v0 - v1`.
    #[inline(always)]
    pub(crate) fn e1(&self) -> Vec3A {
        Vec3A::from_vec4(self.e1)
    }

    /// `v2 - v0`.
    #[inline(always)]
    pub(crate) fn e2(&self) -> Vec3A {
        Vec3A::from_vec4(self.e2)
    }

    /// `e1 x e2`: minus the counter-clockwise normal, length twice the area.
    #[inline(always)]
    pub(crate) fn ng(&self) -> Vec3A {
        Vec3A::from_vec4(self.ng)
    }
}

const _: () = assert!(size_of::<Tri>() == 64);

#[cfg(test)]
mod tests {
    use super::*;
    use obvhs::triangle::Triangle;

    #[test]
    fn ids_round_trip_bit_for_bit() {
        let t = Triangle {
            v0: Vec3A::ZERO,
            v1: Vec3A::X,
            v2: Vec3A::Y,
        };
        let rt = RtTriangle::from(&t);
        for id in [0, 1, 0x7f80_0001, 0xffc0_0000, u32::MAX - 1, 0x8000_0000] {
            let tri = Tri::new(&rt, id);
            assert_eq!(tri.id(), id);
            assert_eq!(
                (tri.v0(), tri.e1(), tri.e2(), tri.ng()),
                (rt.v0, rt.e1, rt.e2, rt.ng)
            );
        }
    }
}
