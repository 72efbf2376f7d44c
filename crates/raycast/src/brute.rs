//! The test oracle: every triangle, intersected in world-space `f64`.

use glam::{DVec3, Vec3};

use crate::{
    BuildError, Hit, NO_ID, Ray, RayCaster, SurfacePoint, exact,
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
        frame.check_lift(bounds.0, bounds.1)?;
        let tris = triangles.iter().map(|t| t.map(|v| v.as_dvec3())).collect();
        Ok(BruteForce {
            tris,
            ids: ids.to_vec(),
            frame,
            bounds,
        })
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

    /// Every hit along the ray (all triangles, both sides, `ray.exclude` skipped), nearest first,
    /// by the same rules as [`RayCaster::closest_hit`]: the first element is what it returns
    /// (up to exact ties).
    pub fn hits_along(&self, ray: &Ray) -> Vec<Hit> {
        let Some(r) = self.frame.world_ray(ray) else {
            return Vec::new();
        };
        let mut hits: Vec<(f64, Hit)> = self
            .candidates(ray.exclude, NO_ID)
            .filter_map(|(tri, id)| {
                let (t, front) =
                    exact::ray_candidate(tri[0], tri[1] - tri[0], tri[2] - tri[0], &r)?;
                Some((t, hit(&r, t, id, front)))
            })
            .collect();
        hits.sort_by(|a, b| a.0.total_cmp(&b.0));
        hits.into_iter().map(|(_, h)| h).collect()
    }

    /// Every blocker of the segment between `a` and `b` (as in [`RayCaster::occluded`]),
    /// nearest to `a` first; `distance` is measured from `a`'s offset point.
    pub fn blockers(&self, a: &SurfacePoint, b: &SurfacePoint) -> Vec<Hit> {
        let Some(seg) = self.frame.world_segment(a, b) else {
            return Vec::new();
        };
        let mut hits: Vec<(f64, Hit)> = self
            .candidates(a.id, b.id)
            .filter_map(|(tri, id)| {
                let (t, front) = exact::blocker(tri[0], tri[1] - tri[0], tri[2] - tri[0], &seg)?;
                Some((t, hit(&seg, t.max(0.0), id, front)))
            })
            .collect();
        hits.sort_by(|a, b| a.0.total_cmp(&b.0));
        hits.into_iter().map(|(_, h)| h).collect()
    }

    /// Triangles whose id is neither `skip_a` nor `skip_b`.
    fn candidates(&self, skip_a: u32, skip_b: u32) -> impl Iterator<Item = (&[DVec3; 3], u32)> {
        self.tris
            .iter()
            .zip(&self.ids)
            .filter_map(move |(tri, &id)| (id != skip_a && id != skip_b).then_some((tri, id)))
    }
}

fn hit(r: &WorldRay, t: f64, id: u32, front: bool) -> Hit {
    Hit {
        id,
        distance: t as f32,
        point: (r.origin + r.dir * t).as_vec3(),
        front,
    }
}

impl RayCaster for BruteForce {
    fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let r = self.frame.world_ray(ray)?;
        let mut best: Option<(f64, u32, bool)> = None;
        for (tri, id) in self.candidates(ray.exclude, NO_ID) {
            let candidate = exact::ray_candidate(tri[0], tri[1] - tri[0], tri[2] - tri[0], &r);
            if let Some((t, front)) = candidate
                && best.is_none_or(|b| t < b.0)
            {
                best = Some((t, id, front));
            }
        }
        let (t, id, front) = best?;
        Some(hit(&r, t, id, front))
    }

    fn occluded(&self, a: &SurfacePoint, b: &SurfacePoint) -> bool {
        let Some(seg) = self.frame.world_segment(a, b) else {
            return false;
        };
        self.candidates(a.id, b.id).any(|(tri, _)| {
            exact::blocker(tri[0], tri[1] - tri[0], tri[2] - tri[0], &seg).is_some()
        })
    }
}
