//! The sky's direct light at a point ([`mcrad_scene_io::Sky`]): part of the lights' pre-pass
//! (`crate::lights`).
//!
//! A point `x` with unit normal `n` receives `H_sky = ∫ L(w) V(x, w) max(0, n · w) dw` (W/m²),
//! `V` 1 where a ray from `x` along `w` leaves the scene. A uniform sky is sampled by cosine,
//! whose density `cos / pi` matches the integrand up to `V`: each ray scores `pi L V`, so an
//! unobstructed patch gets `pi L` without noise and a closed room exactly 0. A map is sampled
//! by cosine and by the map's luminance ([`SkyMap::sample`](mcrad_scene_io::SkyMap::sample)),
//! [`SKY_PAIRS`] rays of each per point (stratified in the square, 2 x 2), combined by the
//! balance heuristic: each ray scores `L V cos / (p_cos + p_map)`, the mean over the pairs is
//! unbiased, and neither a small bright sun in the map nor a dim map over a grazing patch makes
//! the weights blow up.

use glam::{DVec3, Vec3};
use mcrad_random::Stream;
use mcrad_raycast::{RayCaster, SurfacePoint};
use mcrad_scene_io::Sky;
use std::f64::consts::{PI, TAU};

/// Rays of each technique per point (a 2 x 2 stratification of the square).
pub(crate) const SKY_PAIRS: u32 = 4;

/// The sky's shadow rays per point: [`SKY_PAIRS`] for a uniform sky (cosine only), twice that
/// for a map (cosine and map), 0 for a sky that gives no light.
pub(crate) fn rays_per_point(sky: Option<&Sky>) -> u32 {
    match sky {
        None => 0,
        Some(sky) if sky.is_dark() => 0,
        Some(Sky::Uniform(_)) => SKY_PAIRS,
        Some(Sky::Map(_)) => 2 * SKY_PAIRS,
    }
}

/// An estimate of the sky's irradiance at `x` (on a surface of id `own`, which its rays
/// exclude, unit normal `normal`, the mesh's frame: the sky is at infinity, so no offset
/// applies), W/m² per channel, from
/// [`rays_per_point`] rays reaching `far` along their direction; and how many of those rays
/// left the scene (scored).
pub(crate) fn irradiance<C: RayCaster>(
    sky: &Sky,
    own: u32,
    x: Vec3,
    normal: Vec3,
    caster: &C,
    far: f64,
    rng: &mut Stream,
) -> (DVec3, u32) {
    let n = normal.as_dvec3();
    let (t, b) = n.any_orthonormal_pair();
    let from = SurfacePoint::new(x, normal, own);
    let open = |w: DVec3| {
        let target = (x.as_dvec3() + w * far).as_vec3();
        !caster.occluded(&from, &SurfacePoint::free(target))
    };
    let strata = |k: u32, rng: &mut Stream| {
        [
            (f64::from(k % 2) + rng.uniform_f64()) * 0.5,
            (f64::from(k / 2) + rng.uniform_f64()) * 0.5,
        ]
    };
    let cosine = |u: [f64; 2]| {
        let r = u[0].sqrt();
        let phi = TAU * u[1];
        let z = (1.0 - u[0]).max(0.0).sqrt();
        (t * (r * phi.cos()) + b * (r * phi.sin()) + n * z).normalize()
    };
    let mut h = DVec3::ZERO;
    let mut scored = 0;
    match sky {
        Sky::Uniform(l) => {
            for k in 0..SKY_PAIRS {
                let w = cosine(strata(k, rng));
                if n.dot(w) > 0.0 && open(w) {
                    h += *l * PI;
                    scored += 1;
                }
            }
        }
        Sky::Map(map) => {
            for k in 0..SKY_PAIRS {
                // by cosine
                let w = cosine(strata(k, rng));
                let cos = n.dot(w);
                if cos > 0.0 {
                    let pdf = cos / PI + map.pdf(w);
                    if open(w) {
                        h += map.radiance(w) * (cos / pdf);
                        scored += 1;
                    }
                }
                // by the map
                if let Some(s) = map.sample(strata(k, rng)) {
                    let cos = n.dot(s.direction);
                    if cos > 0.0 && open(s.direction) {
                        let pdf = cos / PI + s.pdf;
                        h += map.radiance(s.direction) * (cos / pdf);
                        scored += 1;
                    }
                }
            }
        }
    }
    (h / f64::from(SKY_PAIRS), scored)
}
