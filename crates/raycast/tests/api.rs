//! The public contract: errors, degenerate input, back faces, batches, threads, build time.

mod common;

use common::*;
use glam::{Vec3, vec3};
use mcrad_raycast::{BruteForce, BuildError, Bvh, Hit, NO_ID, Ray, RayCaster, SurfacePoint};
use rayon::prelude::*;

/// A unit square in the plane y = `y`, facing +Y (or -Y), two triangles with one id.
fn square(y: f32, up: bool, id: u32) -> (Vec<[Vec3; 3]>, Vec<u32>) {
    let (a, b, c, d) = (
        vec3(0., y, 0.),
        vec3(1., y, 0.),
        vec3(1., y, 1.),
        vec3(0., y, 1.),
    );
    let tris = if up {
        vec![[a, d, c], [a, c, b]]
    } else {
        vec![[a, b, c], [a, c, d]]
    };
    (tris, vec![id, id])
}

fn casters(tris: &[[Vec3; 3]], ids: &[u32]) -> (Bvh, BruteForce) {
    (
        Bvh::build(tris, ids).unwrap(),
        BruteForce::build(tris, ids).unwrap(),
    )
}

#[test]
fn build_errors_name_the_offender() {
    let (tris, ids) = square(0.0, true, 1);
    assert_eq!(Bvh::build(&[], &[]).unwrap_err(), BuildError::Empty);
    assert_eq!(BruteForce::build(&[], &[]).unwrap_err(), BuildError::Empty);
    assert_eq!(
        Bvh::build(&tris, &ids[..1]).unwrap_err(),
        BuildError::LengthMismatch {
            triangles: 2,
            ids: 1
        }
    );
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let mut t = tris.clone();
        t[1][2].y = bad;
        let e = Bvh::build(&t, &ids).unwrap_err();
        assert!(
            matches!(e, BuildError::NonFiniteVertex { triangle: 1, vertex: 2, value }
                if value.x == 1.0 && !value.y.is_finite()),
            "{e:?}"
        );
        assert!(e.to_string().contains("triangle 1, vertex 2"), "{e}");
        assert_eq!(
            BruteForce::build(&t, &ids).unwrap_err().to_string(),
            e.to_string()
        );
    }
    let e = Bvh::build(&tris, &[3, NO_ID]).unwrap_err();
    assert_eq!(e, BuildError::ReservedId { triangle: 1 });
}

#[test]
fn back_faces_are_reported_and_flagged() {
    let (tris, ids) = square(0.0, true, 7);
    for caster in [
        &casters(&tris, &ids).0 as &dyn RayCaster,
        &casters(&tris, &ids).1,
    ] {
        let down = caster
            .closest_hit(&Ray::new(vec3(0.3, 2.0, 0.6), -Vec3::Y))
            .unwrap();
        assert_eq!((down.id, down.front), (7, true));
        assert!(
            (down.distance - 2.0).abs() < 1e-6
                && (down.point - vec3(0.3, 0.0, 0.6)).length() < 1e-6
        );
        let up = caster
            .closest_hit(&Ray::new(vec3(0.3, -0.5, 0.6), Vec3::Y))
            .unwrap();
        assert_eq!((up.id, up.front), (7, false));
        assert!((up.distance - 0.5).abs() < 1e-6);
        assert!(
            caster
                .closest_hit(&Ray::new(vec3(0.3, 1.0, 0.6), Vec3::Y))
                .is_none()
        );
    }
    // and the closest wins whichever its side: a back face in front of a front face
    let (mut tris, mut ids) = square(1.0, true, 1); // seen from below: back
    let (t2, i2) = square(2.0, false, 2); // seen from below: front
    tris.extend(t2);
    ids.extend(i2);
    let (bvh, _) = casters(&tris, &ids);
    let h = bvh
        .closest_hit(&Ray::new(vec3(0.5, 0.0, 0.5), Vec3::Y))
        .unwrap();
    assert_eq!((h.id, h.front), (1, false));
    let h = bvh
        .closest_hit(&Ray::from_surface(vec3(0.5, 1.0, 0.5), Vec3::Y, Vec3::Y, 1))
        .unwrap();
    assert_eq!((h.id, h.front), (2, true));
}

#[test]
fn surface_rays_skip_their_own_patch_and_start_off_the_surface() {
    // two coplanar patches: a ray leaving one sideways at a grazing angle must not hit either
    let (mut tris, mut ids) = square(0.0, true, 1);
    let (t2, _) = square(0.0, true, 2);
    tris.extend(t2.iter().map(|t| t.map(|v| v + Vec3::X)));
    ids.extend([2, 2]);
    let (ceiling, cid) = square(0.5, false, 3);
    tris.extend(
        ceiling
            .iter()
            .map(|t| t.map(|v| (v - vec3(0.0, 0.5, 0.0)) * 4.0 + vec3(-1.0, 0.5, -1.0))),
    );
    ids.extend(cid);
    let (bvh, oracle) = casters(&tris, &ids);
    let mut rng = Rng::new(5);
    for _ in 0..10_000 {
        let p = vec3(rng.f32(), 0.0, rng.f32());
        let d = grazing_dir(Vec3::Y, &mut rng);
        let r = Ray::from_surface(p, Vec3::Y, d, 1);
        let h = bvh.closest_hit(&r);
        assert!(h.is_none_or(|h| h.id == 3), "{r:?}: {h:?}");
        assert_eq!(h.map(|h| h.id), oracle.closest_hit(&r).map(|h| h.id));
    }
    // the offset is about 1e-6 of the scene
    let eps = bvh.surface_epsilon();
    assert!(eps > 1e-7 && eps < 1e-5, "{eps}");
    assert_eq!(eps, oracle.surface_epsilon());
}

#[test]
fn distances_are_euclidean_whatever_the_direction_length() {
    let s = cornell();
    let (bvh, _) = casters(&s.tris, &s.ids);
    let o = vec3(0.5, 0.5, 0.9);
    let a = bvh
        .closest_hit(&Ray::new(o, vec3(0.0, -1.0, -1.0).normalize()))
        .unwrap();
    let b = bvh
        .closest_hit(&Ray::new(o, vec3(0.0, -7.0, -7.0)))
        .unwrap();
    assert_eq!(a.id, b.id);
    assert!((a.distance - b.distance).abs() < 1e-6 && (a.point - b.point).length() < 1e-6);
    assert!((a.point - (o + vec3(0.0, -1.0, -1.0).normalize() * a.distance)).length() < 1e-6);
}

#[test]
fn degenerate_queries_never_panic() {
    let s = cornell();
    let (bvh, oracle) = casters(&s.tris, &s.ids);
    let p = vec3(0.5, 0.5, 0.5);
    for caster in [&bvh as &dyn RayCaster, &oracle] {
        for (o, d) in [
            (p, Vec3::ZERO),
            (p, Vec3::NAN),
            (p, Vec3::INFINITY),
            (Vec3::NAN, Vec3::X),
            (Vec3::splat(f32::MAX), -Vec3::X),
            (Vec3::splat(1e30), Vec3::ONE),
        ] {
            assert!(caster.closest_hit(&Ray::new(o, d)).is_none(), "{o} {d}");
        }
        // a far camera still sees the scene
        let h = caster
            .closest_hit(&Ray::new(vec3(0.9, 0.9, 1e6), -Vec3::Z))
            .unwrap();
        assert_eq!(h.id, 2);
        // non-unit and NaN normals
        let r = Ray::from_surface(vec3(0.5, 0.0, 0.5), Vec3::Y * 3.0, Vec3::Y, 0);
        assert_eq!(caster.closest_hit(&r).map(|h| h.id), Some(5));
        let r = Ray::from_surface(vec3(0.5, 0.0, 0.5), Vec3::NAN, Vec3::Y, 0);
        assert_eq!(caster.closest_hit(&r).map(|h| h.id), Some(5));
        let a = SurfacePoint::new(vec3(0.5, 0.0, 0.5), Vec3::Y, 0);
        assert!(!caster.occluded(&a, &a));
        assert!(!caster.occluded(&a, &SurfacePoint::free(Vec3::NAN)));
        assert!(!caster.occluded(&a, &SurfacePoint::new(Vec3::INFINITY, Vec3::Y, 1)));
    }
}

#[test]
fn occlusion_ignores_both_end_patches_only() {
    // floor (1), ceiling (2), a blocker (3) halfway between
    let (mut tris, mut ids) = square(0.0, true, 1);
    for (y, up, id) in [(2.0, false, 2), (1.0, true, 3)] {
        let (t, i) = square(y, up, id);
        tris.extend(t);
        ids.extend(i);
    }
    let (bvh, oracle) = casters(&tris, &ids);
    let a = SurfacePoint::new(vec3(0.2, 0.0, 0.3), Vec3::Y, 1);
    let b = SurfacePoint::new(vec3(0.7, 2.0, 0.6), -Vec3::Y, 2);
    let on_blocker = SurfacePoint::new(vec3(0.7, 1.0, 0.6), Vec3::Y, 3);
    let above = SurfacePoint::free(vec3(0.5, 1.5, 0.5));
    for caster in [&bvh as &dyn RayCaster, &oracle] {
        assert!(caster.occluded(&a, &b) && caster.occluded(&b, &a));
        assert!(!caster.occluded(&a, &on_blocker) && !caster.occluded(&on_blocker, &b));
        assert!(!caster.occluded(&above, &b) && caster.occluded(&above, &a));
    }
    assert_eq!(
        oracle
            .blockers(&a, &b)
            .iter()
            .map(|h| h.id)
            .collect::<Vec<_>>(),
        vec![3]
    );
}

#[test]
fn degenerate_scenes_build_and_answer() {
    let p = vec3(1.0, 2.0, 3.0);
    // one point: nothing to hit
    let (bvh, oracle) = casters(&[[p, p, p]], &[0]);
    assert_eq!(bvh.triangle_count(), 1);
    assert_eq!(bvh.bounds(), (p, p));
    assert!(
        bvh.closest_hit(&Ray::new(Vec3::ZERO, p.normalize()))
            .is_none()
    );
    assert!(
        oracle
            .closest_hit(&Ray::new(Vec3::ZERO, p.normalize()))
            .is_none()
    );
    // a single triangle, and a flat scene (zero extent along y)
    let (tris, ids) = square(0.0, true, 4);
    for n in [1, 2] {
        let (bvh, _) = casters(&tris[..n], &ids[..n]);
        let h = bvh
            .closest_hit(&Ray::new(vec3(0.3, 1.0, 0.6), -Vec3::Y))
            .unwrap();
        assert_eq!(h.id, 4);
    }
    // degenerate triangles mixed into a real scene are never hit and spoil nothing
    let mut s = cornell();
    let q = vec3(0.5, 0.5, 0.5);
    s.tris
        .extend([[q, q, q], [q, q + Vec3::X * 0.1, q + Vec3::X * 0.2]]);
    s.ids.extend([100, 101]);
    let (bvh, oracle) = casters(&s.tris, &s.ids);
    let mut rng = Rng::new(6);
    let rays: Vec<Ray> = (0..5_000)
        .map(|_| surface_ray(&s, Spot::Uniform, false, &mut rng))
        .collect();
    let t = compare(&bvh, &oracle, &rays);
    assert!(t.wrong.is_empty() && t.unstable == 0, "{t:?}");
    for r in &rays {
        if let Some(h) = bvh.closest_hit(r) {
            assert!(h.id < 100 && h.distance.is_finite() && h.point.is_finite());
        }
    }
    let along = bvh.closest_hit(&Ray::new(q - Vec3::X * 0.01, Vec3::X));
    assert!(along.is_some_and(|h| h.id < 100));
}

#[test]
fn tiny_and_huge_scenes_answer_like_the_unit_scene() {
    let s = cornell();
    let mut rng = Rng::new(8);
    let rays: Vec<Ray> = (0..2_000)
        .map(|_| surface_ray(&s, Spot::Uniform, false, &mut rng))
        .collect();
    let (unit, _) = casters(&s.tris, &s.ids);
    for sigma in [1e-30f32, 1e30] {
        let scaled = s.map(|v| v * sigma);
        let (bvh, _) = casters(&scaled.tris, &scaled.ids);
        let mut differ = 0;
        for r in &rays {
            let a = unit.closest_hit(r).map(|h| h.id);
            let b = bvh
                .closest_hit(&Ray {
                    origin: r.origin * sigma,
                    ..*r
                })
                .map(|h| h.id);
            differ += usize::from(a != b);
        }
        assert!(differ <= 2, "scale {sigma}: {differ} differ");
    }
}

#[test]
fn batches_match_single_queries_and_tolerate_length_mismatch() {
    let s = room_with_boxes(2, 6);
    let (bvh, _) = casters(&s.tris, &s.ids);
    let mut rng = Rng::new(9);
    let rays: Vec<Ray> = (0..500)
        .map(|_| surface_ray(&s, Spot::Uniform, false, &mut rng))
        .collect();
    let mut hits = vec![None; 400];
    bvh.closest_hit_batch(&rays, &mut hits);
    for (r, h) in rays.iter().zip(&hits) {
        assert_eq!(*h, bvh.closest_hit(r));
    }
    let pairs: Vec<_> = (0..300)
        .map(|_| (surface_point(&s, &mut rng), surface_point(&s, &mut rng)))
        .collect();
    let mut out = vec![false; 500];
    bvh.occluded_batch(&pairs, &mut out);
    for ((a, b), o) in pairs.iter().zip(&out) {
        assert_eq!(*o, bvh.occluded(a, b));
    }
    assert!(out[300..].iter().all(|&o| !o));
}

#[test]
fn one_bvh_serves_many_threads_with_the_same_answers() {
    let s = room_with_boxes(10, 12);
    let bvh = Bvh::build(&s.tris, &s.ids).unwrap();
    let mut rng = Rng::new(10);
    let rays: Vec<Ray> = (0..20_000)
        .map(|_| surface_ray(&s, Spot::Uniform, false, &mut rng))
        .collect();
    let serial: Vec<Option<Hit>> = rays.iter().map(|r| bvh.closest_hit(r)).collect();
    let parallel: Vec<Option<Hit>> = rays.par_iter().map(|r| bvh.closest_hit(r)).collect();
    assert_eq!(serial, parallel);
}

#[test]
fn a_room_of_100k_triangles_builds_a_bvh_over_all_of_them() {
    // How long the build takes is measured by `cargo xtask bench`, not asserted here.
    let s = room_with_boxes(12, 1_900);
    assert!(s.tris.len() > 100_000, "{}", s.tris.len());
    let bvh = Bvh::build(&s.tris, &s.ids).unwrap();
    assert_eq!(bvh.triangle_count(), s.tris.len());
    assert!(bvh.node_count() > 0);
}

#[test]
fn axis_aligned_rays_with_negative_zeros_hit() {
    // -Vec3::Y is (-0, -1, -0); obvhs alone misses with it
    let (tris, ids) = square(0.0, true, 7);
    let (bvh, _) = casters(&tris, &ids);
    for d in [-Vec3::Y, vec3(-0.0, -1.0, 0.0), vec3(0.0, -1.0, -0.0)] {
        let h = bvh.closest_hit(&Ray::new(vec3(0.3, 2.0, 0.6), d));
        assert_eq!(h.map(|h| h.id), Some(7), "{d}");
    }
    let a = SurfacePoint::free(vec3(0.3, 2.0, 0.6));
    let b = SurfacePoint::free(vec3(0.3, -2.0, 0.6));
    assert!(bvh.occluded(&a, &b) && bvh.occluded(&b, &a));
}

#[test]
fn coordinates_up_to_f32_max_build_or_are_refused_clearly() {
    // 40 unit-spaced triangles (more than a leaf holds) scaled by `size` and moved to `at`
    let cluster = |at: Vec3, size: f32| -> (Vec<[Vec3; 3]>, Vec<u32>) {
        let tris = (0..40)
            .map(|i| {
                let c = at + vec3(0.0, i as f32 * size, 0.0);
                [c, c + Vec3::X * size, c + Vec3::Z * size]
            })
            .collect();
        (tris, (0..40).collect())
    };
    // far but large enough for f32 to place its points: built, and rays hit it
    for (at, size) in [
        (vec3(1e36, 0.0, 0.0), 1e31),
        (vec3(-1e20, 1e20, 0.0), 1e15),
        (Vec3::splat(-f32::MAX / 2.0), f32::MAX / 100.0),
    ] {
        let (tris, ids) = cluster(at, size);
        let (bvh, oracle) = casters(&tris, &ids);
        let target = tris[5][0] + (Vec3::X + Vec3::Z) * (size / 3.0);
        let ray = Ray::new(target - Vec3::Y * 0.5 * size, Vec3::Y);
        let (a, b) = (bvh.closest_hit(&ray), oracle.closest_hit(&ray));
        assert!(a.is_some(), "at {at}, size {size}: no hit");
        assert_eq!(a.map(|h| h.id), b.map(|h| h.id), "at {at}, size {size}");
    }
    // far out for its size (1e8 times): origins are lifted by more than the scene's size,
    // so answers are coarse (the solver refuses such scenes), but it builds and answers
    let (tris, ids) = cluster(vec3(1e38, 0.0, 0.0), 1e30);
    let bvh = Bvh::build(&tris, &ids).unwrap();
    let hit = bvh.closest_hit(&Ray::new(tris[5][0] - Vec3::Y * 1e31, Vec3::Y));
    assert!(hit.is_none_or(|h| h.distance.is_finite()));
    // so far out for its size that f32 cannot place its points and box areas would overflow
    // (this panicked in the collapse: infinite costs made a leaf of 40 triangles)
    for (at, size) in [
        (vec3(1e38, 0.0, 0.0), 1e26),
        (vec3(f32::MAX, 0.0, 0.0), 1e25),
    ] {
        let (tris, ids) = cluster(at, size);
        for e in [
            Bvh::build(&tris, &ids).unwrap_err(),
            BruteForce::build(&tris, &ids).unwrap_err(),
        ] {
            assert!(
                matches!(e, BuildError::FarFromOrigin { magnitude, .. } if magnitude >= at.x),
                "{e:?}"
            );
            assert!(
                e.to_string().contains("move the scene near the origin"),
                "{e}"
            );
        }
    }
}
