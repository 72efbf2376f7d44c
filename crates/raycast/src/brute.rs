//! The test oracle: every triangle, intersected in world-space `f64`.

use glam::{DVec3, Vec3};

use crate::{
    BuildError, Hit, Ray, RayCaster, SurfacePoint,
    frame::{self, Frame, WorldRay},
};

/// A ray caster that intersects every triangle in `f64`, in world coordinates: slow (linear in
/// the triangle count) and as exact as the `f32` input allows. It offsets ray origins exactly
/// like [`Bvh`](crate::Bvh) (same canonical frame, same lift, same minimum distance), so the two
/// must agree except on genuine ties. Use it as the oracle in tests.
#[derive(Clone, Debug)]
pub struct BruteForce {
    /// Input triangles, world coordinates.
    tris: Vec<[DVec3; 3]>,
    /// Caller's primitive id per triangle.
    ids: Vec<u32>,
    /// The frame that decides origin offsets.
    frame: Frame,
    /// World bounds (min, max) of all input vertices.
    bounds: (Vec3, Vec3),
}

impl BruteForce {
    /// Same contract as [`Bvh::build`](crate::Bvh::build).
    pub fn build(triangles: &[[Vec3; 3]], ids: &[u32]) -> Result<BruteForce, BuildError> {
        let bounds = frame::validate(triangles, ids)?;
        let frame = Frame::new(bounds.0, bounds.1);
        let tris = triangles.iter().map(|t| t.map(|v| v.as_dvec3())).collect();
        Ok(BruteForce { tris, ids: ids.to_vec(), frame, bounds })
    }

    /// Number of input triangles.
    pub fn triangle_count(&self) -> usize {
        self.tris.len()
    }

    /// Bounds `(min, max)` of all input vertices, in scene units.
    pub fn bounds(&self) -> (Vec3, Vec3) {
        self.bounds
    }

    /// [`CANONICAL_EPSILON`](crate::CANONICAL_EPSILON) in scene units (same as the
    /// [`Bvh`](crate::Bvh) over the same triangles).
    pub fn surface_epsilon(&self) -> f32 {
        self.frame.world_epsilon() as f32
    }

    /// Every hit along the ray (all triangles, both sides, `ray.exclude` skipped), nearest first.
    /// The first element is what [`RayCaster::closest_hit`] returns (up to exact ties).
    pub fn hits_along(&self, ray: &Ray) -> Vec<Hit> {
        let Some(r) = self.frame.world_ray(ray) else {
            return Vec::new();
        };
        self.collect(&r, |id| id == ray.exclude)
    }

    /// Every blocker of the segment between `a` and `b` (as in [`RayCaster::occluded`]),
    /// nearest to `a` first; `distance` is measured from `a`'s offset point.
    pub fn blockers(&self, a: &SurfacePoint, b: &SurfacePoint) -> Vec<Hit> {
        let Some(r) = self.frame.world_segment(a, b) else {
            return Vec::new();
        };
        self.collect(&r, |id| id == a.id || id == b.id)
    }

    fn collect(&self, r: &WorldRay, skip: impl Fn(u32) -> bool) -> Vec<Hit> {
        let mut hits: Vec<(f64, Hit)> = self
            .tris
            .iter()
            .zip(&self.ids)
            .filter(|&(_, &id)| !skip(id))
            .filter_map(|(tri, &id)| {
                let (t, front) = intersect(tri, r)?;
                let point = (r.origin + r.dir * t).as_vec3();
                Some((t, Hit { id, distance: t as f32, point, front }))
            })
            .collect();
        hits.sort_by(|a, b| a.0.total_cmp(&b.0));
        hits.into_iter().map(|(_, h)| h).collect()
    }
}

impl RayCaster for BruteForce {
    fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let r = self.frame.world_ray(ray)?;
        let mut best: Option<(f64, u32, bool)> = None;
        for (tri, &id) in self.tris.iter().zip(&self.ids) {
            if id == ray.exclude {
                continue;
            }
            if let Some((t, front)) = intersect(tri, &r) {
                if best.is_none_or(|b| t < b.0) {
                    best = Some((t, id, front));
                }
            }
        }
        let (t, id, front) = best?;
        Some(Hit { id, distance: t as f32, point: (r.origin + r.dir * t).as_vec3(), front })
    }

    fn occluded(&self, a: &SurfacePoint, b: &SurfacePoint) -> bool {
        let Some(r) = self.frame.world_segment(a, b) else {
            return false;
        };
        self.tris
            .iter()
            .zip(&self.ids)
            .any(|(tri, &id)| id != a.id && id != b.id && intersect(tri, &r).is_some())
    }
}

/// The exact test on a stored triangle, in the ray's frame.
fn intersect(tri: &[DVec3; 3], r: &WorldRay) -> Option<(f64, bool)> {
    crate::exact::intersect(tri[0], tri[1] - tri[0], tri[2] - tri[0], r)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn world_ray(o: DVec3, d: DVec3) -> WorldRay {
        WorldRay { origin: o, dir: d, tmin: 0.0, tmax: f64::INFINITY }
    }

    #[test]
    fn moller_trumbore_orientation_edges_and_planes() {
        let tri = [DVec3::ZERO, DVec3::X, DVec3::Y]; // normal +Z
        let down = world_ray(DVec3::new(0.25, 0.25, 1.0), -DVec3::Z);
        assert_eq!(intersect(&tri, &down), Some((1.0, true)));
        let up = world_ray(DVec3::new(0.25, 0.25, -2.0), DVec3::Z);
        assert_eq!(intersect(&tri, &up), Some((2.0, false)));
        // exactly on an edge and on a vertex: closed triangle
        assert!(intersect(&tri, &world_ray(DVec3::new(0.5, 0.0, 1.0), -DVec3::Z)).is_some());
        assert!(intersect(&tri, &world_ray(DVec3::new(0.0, 1.0, 1.0), -DVec3::Z)).is_some());
        assert!(intersect(&tri, &world_ray(DVec3::new(0.6, 0.6, 1.0), -DVec3::Z)).is_none());
        // in the plane: no hit; behind: no hit
        assert!(intersect(&tri, &world_ray(DVec3::new(-1.0, 0.2, 0.0), DVec3::X)).is_none());
        assert!(intersect(&tri, &world_ray(DVec3::new(0.2, 0.2, 1.0), DVec3::Z)).is_none());
        // degenerate
        let line = [DVec3::ZERO, DVec3::X, DVec3::X * 2.0];
        assert!(intersect(&line, &down).is_none());
    }
}
