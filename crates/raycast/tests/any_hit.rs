//! The any-hit test: a checkered card over a floor lets rays through its odd cells, for the
//! closest hit and for occlusion, on every SIMD level, and leaves the other ids alone.

use std::sync::Arc;

use glam::Vec3;
use mcrad_raycast::{AnyHit, Bvh, Ray, RayCaster, Simd, SurfacePoint};
use rand_core::Rng as _;
use rand_pcg::Pcg32;

/// Card (id 1) cells of a 4 × 4 checker: odd cells let rays pass.
struct Checker;

impl AnyHit for Checker {
    fn passes(&self, id: u32, point: Vec3, _dir: Vec3) -> bool {
        id == 1 && odd(point)
    }
}

fn odd(p: Vec3) -> bool {
    ((p.x * 4.0).floor() as i32 + (p.z * 4.0).floor() as i32).rem_euclid(2) == 1
}

/// A unit square at height `y` facing up, as two triangles.
fn square(y: f32) -> [[Vec3; 3]; 2] {
    let (a, b, c, d) = (
        Vec3::new(0., y, 0.),
        Vec3::new(1., y, 0.),
        Vec3::new(1., y, 1.),
        Vec3::new(0., y, 1.),
    );
    [[a, d, c], [a, c, b]]
}

#[test]
fn cut_out_cells_let_rays_and_segments_pass() {
    let mut triangles = square(0.0).to_vec();
    triangles.extend(square(1.0));
    let ids = [0, 0, 1, 1];
    let plain = Bvh::build(&triangles, &ids).unwrap();
    let masked = Bvh::build(&triangles, &ids)
        .unwrap()
        .with_any_hit(Arc::new(Checker));
    let mut rng = Pcg32::new(7, 11);
    let mut uniform = || (rng.next_u32() >> 8) as f32 / (1u32 << 24) as f32;
    let mut passed = 0;
    for _ in 0..2000 {
        let (x, z) = (uniform(), uniform());
        // from above, slanted a little: the card's crossing decides
        let dir = Vec3::new(0.1 * (uniform() - 0.5), -1.0, 0.1 * (uniform() - 0.5)).normalize();
        let origin = Vec3::new(x, 2.0, z);
        let at_card = origin + dir * (1.0 / -dir.y);
        if !(0.0..1.0).contains(&at_card.x) || !(0.0..1.0).contains(&at_card.z) {
            continue;
        }
        let at_floor = origin + dir * (2.0 / -dir.y);
        let floor_inside = (0.0..1.0).contains(&at_floor.x) && (0.0..1.0).contains(&at_floor.z);
        let ray = Ray::new(origin, dir);
        assert_eq!(plain.closest_hit(&ray).map(|h| h.id), Some(1));
        for simd in [Simd::Portable, Simd::Avx2, Simd::Avx512] {
            let bvh = Bvh::build(&triangles, &ids)
                .unwrap()
                .with_any_hit(Arc::new(Checker))
                .with_simd(simd);
            let hit = bvh.closest_hit(&ray).map(|h| h.id);
            let expected = if !odd(at_card) {
                Some(1)
            } else if floor_inside {
                Some(0)
            } else {
                None
            };
            assert_eq!(hit, expected, "{origin} {dir} {simd:?}");
        }
        // the segment from the floor point up to the origin: blocked by opaque cells only
        if floor_inside {
            let a = SurfacePoint::new(at_floor, Vec3::Y, 0);
            let b = SurfacePoint::free(origin);
            assert_eq!(masked.occluded(&a, &b), !odd(at_card));
            assert!(plain.occluded(&a, &b));
            passed += usize::from(odd(at_card));
        }
    }
    assert!(passed > 500, "{passed} segments through cut-out cells");
}

/// An any-hit test that casts rays itself (on another BVH, on the same thread): the card's
/// cells pass where a ray straight down from the crossing, on a BVH of the floor alone, would
/// find the floor's odd cells (the floor of `inner`, ids 5 and 6, cut like the checker): the
/// answers of the checker. (On deeper hierarchies the nested query finds the thread's stack
/// array in use and takes one of its own: `nested_queries_take_a_stack_of_their_own` in
/// `bvh.rs`.)
struct Nested(Bvh);

impl AnyHit for Nested {
    fn passes(&self, id: u32, point: Vec3, _dir: Vec3) -> bool {
        id == 1
            && self
                .0
                .closest_hit(&Ray::new(point, -Vec3::Y))
                .is_some_and(|h| odd(h.point))
    }
}

#[test]
fn an_any_hit_test_may_cast_rays() {
    let mut triangles = square(0.0).to_vec();
    triangles.extend(square(1.0));
    let ids = [0, 0, 1, 1];
    let checker = Bvh::build(&triangles, &ids)
        .unwrap()
        .with_any_hit(Arc::new(Checker));
    let inner = Bvh::build(&square(0.0), &[5, 6]).unwrap();
    let nested = Bvh::build(&triangles, &ids)
        .unwrap()
        .with_any_hit(Arc::new(Nested(inner)));
    let mut rng = Pcg32::new(9, 13);
    let mut uniform = || (rng.next_u32() >> 8) as f32 / (1u32 << 24) as f32;
    let (mut passed, mut blocked) = (0, 0);
    for _ in 0..2000 {
        let origin = Vec3::new(uniform(), 2.0, uniform());
        let target = Vec3::new(uniform(), 0.0, uniform());
        let dir = (target - origin).normalize();
        let ray = Ray::new(origin, dir);
        let hit = nested.closest_hit(&ray).map(|h| h.id);
        assert_eq!(hit, checker.closest_hit(&ray).map(|h| h.id), "{ray:?}");
        let (a, b) = (
            SurfacePoint::free(origin),
            SurfacePoint::new(target, Vec3::Y, 0),
        );
        let occluded = nested.occluded(&a, &b);
        assert_eq!(occluded, checker.occluded(&a, &b), "{a:?} {b:?}");
        passed += usize::from(hit == Some(0));
        blocked += usize::from(occluded);
    }
    assert!(
        passed > 500 && blocked > 500,
        "{passed} passed, {blocked} blocked"
    );
}
