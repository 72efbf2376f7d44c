//! Scale and position independence: the canonical frame makes a scene in millimetres, one in
//! kilometres and one far from the origin see the same canonical numbers.

mod common;

use common::*;
use glam::{Mat3, Vec3, vec3};
use mcrad_raycast::{BruteForce, Bvh, Hit, Ray, RayCaster};

const RAYS: usize = 10_000;

/// Seeded rays of every kind in the base (unit) scene.
fn base_rays(s: &Scene, seed: u64) -> Vec<Ray> {
    let mut rng = Rng::new(seed);
    let kinds = [
        (Spot::Uniform, false),
        (Spot::Edge, false),
        (Spot::Corner, false),
        (Spot::Uniform, true),
        (Spot::Edge, true),
    ];
    (0..RAYS)
        .map(|i| {
            let (spot, grazing) = kinds[i % kinds.len()];
            surface_ray(s, spot, grazing, &mut rng)
        })
        .collect()
}

fn moved(rays: &[Ray], f: impl Fn(Vec3) -> Vec3) -> Vec<Ray> {
    rays.iter()
        .map(|r| Ray {
            origin: f(r.origin),
            ..*r
        })
        .collect()
}

fn hits(bvh: &Bvh, rays: &[Ray]) -> Vec<Option<Hit>> {
    rays.iter().map(|r| bvh.closest_hit(r)).collect()
}

#[test]
fn millimetres_and_kilometres_give_the_same_hits() {
    let base = cornell();
    let rays = base_rays(&base, 21);
    let scaled = |sigma: f32| {
        let s = base.map(|v| v * sigma);
        (
            Bvh::build(&s.tris, &s.ids).unwrap(),
            moved(&rays, |p| p * sigma),
        )
    };
    let (mm, mm_rays) = scaled(1e-3);
    let (m, m_rays) = scaled(1.0);
    let (km, km_rays) = scaled(1e3);
    let km_scene = base.map(|v| v * 1e3);
    let km_oracle = BruteForce::build(&km_scene.tris, &km_scene.ids).unwrap();
    let (h_mm, h_m, h_km) = (hits(&mm, &mm_rays), hits(&m, &m_rays), hits(&km, &km_rays));
    // each is right (ids, sides and distances, up to ties and unstable queries) ...
    for (bvh, rays, sigma) in [
        (&mm, &mm_rays, 1e-3f32),
        (&m, &m_rays, 1.0),
        (&km, &km_rays, 1e3),
    ] {
        let s = base.map(|v| v * sigma);
        let t = compare(bvh, &BruteForce::build(&s.tris, &s.ids).unwrap(), rays);
        assert!(
            t.wrong.is_empty() && t.unstable <= RAYS / 1000,
            "scale {sigma}: {t:?}"
        );
    }
    // ... and they agree with each other
    let mut tally = Tally::default();
    for i in 0..RAYS {
        for other in [h_mm[i], h_m[i]] {
            let same = match (other, h_km[i]) {
                (None, None) => true,
                (Some(a), Some(b)) => a.id == b.id && a.front == b.front,
                _ => false,
            };
            if same {
                tally.same += 1;
                continue;
            }
            // allowed only where the km oracle calls it a genuine tie or an unstable query
            let as_km = other.map(|h| Hit {
                distance: h.distance * 1e3 / 1e-3,
                ..h
            });
            let v = judge(&km_oracle, &km_rays[i], as_km);
            assert!(!matches!(v, Verdict::Wrong(_)), "ray {i}: {v:?}");
            tally.add(v);
        }
    }
    assert!(tally.ties + tally.unstable <= RAYS / 1000, "{tally:?}");
}

#[test]
fn far_from_the_origin_exactly_representable_scenes_are_identical() {
    // Power-of-two scales and a translation of 2^14 extents on a 2^-9 grid: every world
    // coordinate is exact, so the two canonical frames must hold bit-identical triangles and rays.
    let base = cornell().map(|v| (v * 512.0).round() / 512.0);
    let rays = base_rays(&base, 22);
    let far = |sigma: f32| {
        let f = move |p: Vec3| (p + Vec3::splat(16384.0)) * sigma;
        let s = base.map(f);
        (Bvh::build(&s.tris, &s.ids).unwrap(), moved(&rays, f), s)
    };
    let (mm, mm_rays, _) = far(2f32.powi(-10));
    let (km, km_rays, km_scene) = far(2f32.powi(10));
    assert_eq!(mm.bounds().0 * 2f32.powi(20), km.bounds().0);
    for i in 0..RAYS {
        let (a, b) = (mm.closest_hit(&mm_rays[i]), km.closest_hit(&km_rays[i]));
        match (a, b) {
            (None, None) => {}
            (Some(a), Some(b)) => {
                assert_eq!((a.id, a.front), (b.id, b.front), "ray {i}");
                assert_eq!(a.distance * 2f32.powi(20), b.distance, "ray {i}");
                assert_eq!(a.point * 2f32.powi(20), b.point, "ray {i}");
            }
            _ => panic!("ray {i}: {a:?} vs {b:?}"),
        }
    }
    // and they are right
    let oracle = BruteForce::build(&km_scene.tris, &km_scene.ids).unwrap();
    let t = compare(&km, &oracle, &km_rays);
    assert!(t.wrong.is_empty() && t.unstable <= RAYS / 100, "{t:?}");
}

#[test]
fn scenes_far_from_the_origin_match_their_oracle() {
    for (name, base, extent) in [
        ("cornell", cornell(), 1.0f32),
        ("room", room_with_boxes(8, 12), 5.0),
    ] {
        for sigma in [1e-3f32, 1e3] {
            let offset = vec3(1.1, -0.7, 1.3) * (1e4 * extent);
            let s = base.map(|v| (v + offset) * sigma);
            let rays = moved(&base_rays(&base, 23), |p| (p + offset) * sigma);
            let bvh = Bvh::build(&s.tris, &s.ids).unwrap();
            let oracle = BruteForce::build(&s.tris, &s.ids).unwrap();
            let t = compare(&bvh, &oracle, &rays);
            let what = format!("{name} x {sigma} at 1e4 extents: {t:?}");
            assert!(t.wrong.is_empty() && t.unstable <= RAYS / 100, "{what}");
        }
    }
}

#[test]
fn rays_from_a_finely_cut_floor_far_from_the_origin_never_hit_the_floor() {
    // A tilted 64 x 64 floor of separate patches, 100 extents from the origin: surface points
    // computed in world f32 sit up to half an ulp of 100 (several canonical offsets) off their
    // plane, while the floor itself stays flat to 4e-4 of a cell. The adaptive lift must keep
    // every ray above the neighbouring patches (a fixed lift of one canonical offset does not).
    let rot = Mat3::from_euler(glam::EulerRot::YXZ, 0.3, 0.2, 0.1);
    let offset = vec3(120.0, 90.0, -110.0);
    let mut base = Scene::default();
    let p = vec3;
    base.quad(
        [p(0., 0., 0.), p(0., 0., 1.), p(1., 0., 1.), p(1., 0., 0.)],
        64,
        true,
    );
    let floor_patches = base.ids.iter().max().copied().unwrap();
    base.quad(
        [p(0., 1., 0.), p(1., 1., 0.), p(1., 1., 1.), p(0., 1., 1.)],
        1,
        false,
    );
    let s = base.map(|v| rot * v + offset);
    let bvh = Bvh::build(&s.tris, &s.ids).unwrap();
    let mut rng = Rng::new(24);
    let floor_tris = 2 * 64 * 64;
    let (mut below, mut hits_on_floor) = (0, 0);
    for i in 0..RAYS {
        let tri = rng.below(floor_tris);
        let n = s.normal(tri);
        let spot = if i % 4 == 0 {
            Spot::Edge
        } else {
            Spot::Uniform
        };
        let point = point_on(&s, tri, spot, &mut rng);
        // cosine directions, but not steeper than the floor's own bumps allow (cos >= 0.05)
        let dir = loop {
            let d = cosine_dir(n, &mut rng);
            if d.dot(n) >= 0.05 {
                break d;
            }
        };
        // how far below its own plane the f32 point is (f64)
        let [a, _, _] = s.tris[tri].map(|v| v.as_dvec3());
        if (point.as_dvec3() - a).dot(n.as_dvec3()) < -(bvh.surface_epsilon() as f64) {
            below += 1;
        }
        let hit = bvh.closest_hit(&Ray::from_surface(point, n, dir, s.ids[tri]));
        if hit.is_some_and(|h| h.id <= floor_patches) {
            hits_on_floor += 1;
        }
    }
    assert!(
        below > RAYS / 20,
        "the test must exercise origins below their plane: {below}"
    );
    assert_eq!(hits_on_floor, 0);
}
