//! Faces to patches: the radiosity mesh.
//!
//! A [`Mesh`] holds the patches `P_i` the radiosity system is solved over — each a planar convex
//! polygon with area `A_i`, unit normal, centroid, reflectance `rho_i` and emitted radiosity `E_i`
//! — plus the triangles that make them up (for ray casting and uniform point sampling) and shared
//! vertices (so radiosity can later be reconstructed at vertices).
//!
//! With [`Subdivision::None`] there is one patch per input face, in face order. With
//! [`Subdivision::MaxEdge`] every face is cut uniformly — triangles into `n²` similar triangles,
//! quads into an `n_u × n_v` bilinear grid, other polygons fanned into triangles first — until no
//! patch edge is longer than the limit. Sub-patches tile their face exactly, so each face's area
//! is preserved to rounding. Points on a face edge are shared with the neighbouring face whenever
//! both cut that edge into the same number of pieces (always true for the walls of boxes); where
//! they do not, the mesh has T-junctions, which patch radiosity does not mind.

mod adaptive;
mod alpha;
mod build;
mod cluster;
mod coarse;
mod corner_values;
mod discretization;
mod reconstruct;
mod seams;
mod smooth;
mod subdivide;

pub use adaptive::{
    AdaptiveBounds, AdaptiveMesh, AdaptiveStart, DEFAULT_COARSE_EDGE_FRACTION, DEFAULT_MAX_PATCHES,
    DEFAULT_MIN_EDGE_FRACTION, History, Refinement,
};
pub use alpha::AlphaTest;
pub use build::{
    DEFAULT_MAX_EDGE_FRACTION, F32_SPACINGS_PER_PATCH, MIN_COVERAGE, Mesh, MeshError, Patch,
    Subdivision,
};
pub use cluster::{ClusterBounds, Clusters, DEFAULT_CLUSTER_CONE_DEGREES};
pub use coarse::{Carrier, Carry, ClusteredMesh, MAX_CLUSTER_MEMBERS, UNGROUPED};
pub use corner_values::CornerValues;
pub use seams::EdgePoints;
pub use smooth::{CornerGroups, DEFAULT_CREASE_ANGLE_DEGREES};

#[cfg(test)]
mod tests;

#[cfg(test)]
mod adaptive_tests;
