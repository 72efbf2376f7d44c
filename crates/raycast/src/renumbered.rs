//! Another caster's primitives seen under new ids: groups of its ids answered as one id each
//! (the elements of a coarser mesh over the same triangles), without a second hierarchy.

use crate::{Hit, NO_ID, Ray, RayCaster, SurfacePoint};

/// `inner` with its ids renumbered by a table `outer` (inner id `i` is outer id `outer[i]`):
/// a hit on inner id `i` reports `outer[i]`, and a query that excludes outer id `o` (a ray's
/// [`Ray::exclude`], a segment end's [`SurfacePoint::id`]) excludes the one inner id that
/// stands for it. An outer id that stands for several inner ids (a group) excludes none of
/// them: a group may block or be hit by a ray that leaves it (as across a fold between its
/// members). The hits, misses and distances are `inner`'s: the same triangles, one hierarchy
/// for both numberings (memory: 4 bytes per outer id beside the borrowed table).
pub struct Renumbered<'a, C: ?Sized> {
    inner: &'a C,
    /// For each inner id, its outer id.
    outer: &'a [u32],
    /// For each outer id, the one inner id that stands for it, or [`NO_ID`] (none, or several).
    inner_of: Vec<u32>,
}

impl<'a, C: RayCaster + ?Sized> Renumbered<'a, C> {
    /// `inner` seen through `outer` (see the type's documentation); `outer` covers every inner
    /// id a hit may report, and its values below [`NO_ID`] are the outer ids.
    pub fn new(inner: &'a C, outer: &'a [u32]) -> Renumbered<'a, C> {
        let len = outer
            .iter()
            .filter(|&&o| o != NO_ID)
            .max()
            .map_or(0, |&o| o as usize + 1);
        // NO_ID - 1 marks an outer id not yet seen, NO_ID one seen more than once
        const UNSEEN: u32 = NO_ID - 1;
        let mut inner_of = vec![UNSEEN; len];
        for (i, &o) in outer.iter().enumerate().filter(|(_, o)| **o != NO_ID) {
            let slot = &mut inner_of[o as usize];
            *slot = if *slot == UNSEEN { i as u32 } else { NO_ID };
        }
        for slot in &mut inner_of {
            if *slot == UNSEEN {
                *slot = NO_ID;
            }
        }
        Renumbered {
            inner,
            outer,
            inner_of,
        }
    }

    /// The inner id a query that excludes outer id `o` excludes.
    #[inline]
    fn inner_id(&self, o: u32) -> u32 {
        self.inner_of.get(o as usize).copied().unwrap_or(NO_ID)
    }

    /// `hit` under the outer ids.
    #[inline]
    fn outer_hit(&self, mut hit: Hit) -> Hit {
        hit.id = self.outer.get(hit.id as usize).copied().unwrap_or(NO_ID);
        hit
    }

    /// `ray` under the inner ids.
    #[inline]
    fn inner_ray(&self, ray: &Ray) -> Ray {
        Ray {
            exclude: self.inner_id(ray.exclude),
            ..*ray
        }
    }

    /// `p` under the inner ids.
    #[inline]
    fn inner_point(&self, p: &SurfacePoint) -> SurfacePoint {
        SurfacePoint {
            id: self.inner_id(p.id),
            ..*p
        }
    }
}

impl<C: RayCaster + ?Sized> RayCaster for Renumbered<'_, C> {
    fn closest_hit(&self, ray: &Ray) -> Option<Hit> {
        let hit = self.inner.closest_hit(&self.inner_ray(ray))?;
        Some(self.outer_hit(hit))
    }

    fn occluded(&self, a: &SurfacePoint, b: &SurfacePoint) -> bool {
        self.inner
            .occluded(&self.inner_point(a), &self.inner_point(b))
    }

    /// The inner caster's batch (its order of visits), on the rays under the inner ids.
    fn closest_hit_batch(&self, rays: &[Ray], hits: &mut [Option<Hit>]) {
        let rays: Vec<Ray> = rays.iter().map(|r| self.inner_ray(r)).collect();
        self.inner.closest_hit_batch(&rays, hits);
        for hit in hits.iter_mut().take(rays.len()) {
            *hit = hit.map(|h| self.outer_hit(h));
        }
    }

    fn occluded_batch(&self, pairs: &[(SurfacePoint, SurfacePoint)], out: &mut [bool]) {
        let pairs: Vec<(SurfacePoint, SurfacePoint)> = pairs
            .iter()
            .map(|(a, b)| (self.inner_point(a), self.inner_point(b)))
            .collect();
        self.inner.occluded_batch(&pairs, out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{BruteForce, Bvh};
    use glam::Vec3;

    /// Three unit squares facing +z at z = 1, 2, 3 (two triangles each, ids 0-5 by triangle:
    /// square k is ids 2k and 2k + 1).
    fn stack() -> (Vec<[Vec3; 3]>, Vec<u32>) {
        let (mut triangles, mut ids) = (Vec::new(), Vec::new());
        for k in 0..3 {
            let z = (k + 1) as f32;
            let c = [
                Vec3::new(0.0, 0.0, z),
                Vec3::new(1.0, 0.0, z),
                Vec3::new(1.0, 1.0, z),
                Vec3::new(0.0, 1.0, z),
            ];
            triangles.push([c[0], c[1], c[2]]);
            triangles.push([c[0], c[2], c[3]]);
            ids.extend([2 * k, 2 * k + 1]);
        }
        (triangles, ids)
    }

    #[test]
    fn hits_report_the_outer_ids_and_exclusions_the_inner_ones() {
        let (triangles, ids) = stack();
        // outer: square 0's triangles are group 0; square 1's triangles 1 and 2; square 2's
        // triangles 3 and 4
        let outer = [0, 0, 1, 2, 3, 4];
        let casters: [Box<dyn RayCaster>; 2] = [
            Box::new(Bvh::build(&triangles, &ids).unwrap()),
            Box::new(BruteForce::build(&triangles, &ids).unwrap()),
        ];
        for caster in &casters {
            let r = Renumbered::new(caster.as_ref(), &outer);
            let up = |x: f32, y: f32, exclude: u32| Ray {
                origin: Vec3::new(x, y, 0.0),
                dir: Vec3::Z,
                origin_normal: Vec3::ZERO,
                exclude,
            };
            // below the stack: square 0's two triangles are group 0
            assert_eq!(r.closest_hit(&up(0.7, 0.2, NO_ID)).unwrap().id, 0);
            assert_eq!(r.closest_hit(&up(0.2, 0.7, NO_ID)).unwrap().id, 0);
            // excluding group 0 excludes nothing: it stands for two inner ids
            assert_eq!(r.closest_hit(&up(0.7, 0.2, 0)).unwrap().id, 0);
            // excluding outer 0's neighbours: outer 1 is inner 2 (square 1's first triangle)
            let from_1 = Ray {
                origin: Vec3::new(0.7, 0.2, 2.0),
                origin_normal: Vec3::Z,
                ..up(0.7, 0.2, 1)
            };
            let hit = r.closest_hit(&from_1).unwrap();
            assert_eq!((hit.id, hit.distance.round()), (3, 1.0));
            let mut hits = [None; 3];
            r.closest_hit_batch(
                &[up(0.7, 0.2, NO_ID), from_1, up(5.0, 5.0, NO_ID)],
                &mut hits,
            );
            assert_eq!(hits.map(|h| h.map(|h| h.id)), [Some(0), Some(3), None]);
            // a segment between squares 0 and 2 is blocked by square 1; ends on their own
            // surfaces never block
            let a = SurfacePoint::new(Vec3::new(0.7, 0.2, 1.0), Vec3::Z, 0);
            let b = SurfacePoint::new(Vec3::new(0.7, 0.2, 3.0), -Vec3::Z, 3);
            let c = SurfacePoint::new(Vec3::new(0.7, 0.2, 2.0), Vec3::Z, 1);
            assert!(r.occluded(&a, &b));
            assert!(!r.occluded(&c, &b));
            let mut out = [true; 2];
            r.occluded_batch(&[(a, b), (c, b)], &mut out);
            assert_eq!(out, [true, false]);
        }
    }
}
