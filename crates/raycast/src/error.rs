//! Errors of [`Bvh::build`](crate::Bvh::build) and [`BruteForce::build`](crate::BruteForce::build).

use glam::Vec3;

/// Why a triangle list could not be turned into a ray caster.
///
/// Every variant is the caller's responsibility (bad input), and carries the offending indices
/// and numbers so the message can point at the face.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum BuildError {
    /// The triangle list is empty: there is nothing to intersect.
    #[error("no triangles to build a ray caster from")]
    Empty,
    /// `triangles` and `ids` must have one entry per triangle.
    #[error("{triangles} triangles but {ids} ids: need one id per triangle")]
    LengthMismatch {
        /// Number of triangles passed.
        triangles: usize,
        /// Number of ids passed.
        ids: usize,
    },
    /// A vertex has a NaN or infinite coordinate (obvhs would panic or build garbage).
    #[error("triangle {triangle}, vertex {vertex} is not finite: {value}")]
    NonFiniteVertex {
        /// Index of the triangle in the input list.
        triangle: usize,
        /// Which of its three vertices (0, 1 or 2).
        vertex: usize,
        /// The offending position (scene units).
        value: Vec3,
    },
    /// An indexed triangle ([`Bvh::build_indexed`](crate::Bvh::build_indexed)) names a vertex
    /// past the positions.
    #[error("triangle {triangle} names vertex {index}, but there are {positions} positions")]
    VertexIndex {
        /// Index of the triangle in the input list.
        triangle: usize,
        /// The vertex index it names.
        index: u32,
        /// Number of positions passed.
        positions: usize,
    },
    /// A triangle carries the reserved id [`NO_ID`](crate::NO_ID), which means "no primitive"
    /// in rays and surface points.
    #[error("triangle {triangle} has the reserved id NO_ID (u32::MAX)")]
    ReservedId {
        /// Index of the triangle in the input list.
        triangle: usize,
    },
    /// The scene lies so far from the origin, for its size (about `2^31` times its extent or
    /// more), that `f32` coordinates cannot place points on it: the surface offsets of ray
    /// origins (which grow with the distance from the origin, see the crate docs) would dwarf
    /// the scene and overflow the hierarchy's box areas. Refused rather than traced wrongly;
    /// coordinates up to `f32::MAX` are otherwise accepted.
    #[error(
        "the scene is {extent} units across but reaches {magnitude:e} units from the origin, \
         where f32 coordinates are {spacing} apart: too coarse to trace rays on it (move the \
         scene near the origin)"
    )]
    FarFromOrigin {
        /// The largest coordinate magnitude (scene units).
        magnitude: f32,
        /// The largest side of the scene's bounding box (scene units).
        extent: f32,
        /// The spacing of `f32` values at `magnitude` (scene units).
        spacing: f32,
    },
    /// A pair of [`Bvh::with_back_sides`](crate::Bvh::with_back_sides) is refused: an id is
    /// [`NO_ID`](crate::NO_ID), both ids are equal, an id appears in two pairs, or an id is
    /// beyond `4 * triangles + 1024` (the id tables are dense, 8 bytes per id up to the largest).
    #[error("back side pair {pair} ({front}, {back}) is invalid: {reason}")]
    BadBackSide {
        /// Index of the pair in the input list.
        pair: usize,
        /// The pair's front (triangle) id.
        front: u32,
        /// The pair's back id.
        back: u32,
        /// What is wrong with it.
        reason: &'static str,
    },
    /// The hierarchy would hold more triangle slots than the traversal can address
    /// (`2^29` packets of 4, counting triangles that spatial splits put in several leaves and
    /// the unused lanes of packets).
    #[error("{slots} triangle slots in the BVH: at most 2^31 are supported")]
    TooManyTriangles {
        /// Number of slots the build produced.
        slots: usize,
    },
}
