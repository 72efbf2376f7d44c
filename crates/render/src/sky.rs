//! The sky's direct light at a surface point, sampled with rays towards the sky: what renders
//! draw per pixel sample and bakes per texel, so that only the indirect light is interpolated
//! from the mesh.

use glam::{DVec3, Vec3};
use mcrad_random::Stream;
use mcrad_raycast::{RayCaster, SurfacePoint};
use mcrad_scene_io::{Sky, SkyMap};
use std::f64::consts::{PI, TAU};

/// One unbiased estimate of the sky's direct irradiance `H_sky = ∫ L(w) V(x, w) max(0, n · w) dw`
/// (W/m² per channel) at `point` of patch `patch` (unit front normal `normal`, the caster's
/// frame; `V` is 1 where a ray along `w` from the point leaves the scene, tested up to `far`).
///
/// A uniform sky of radiance `L` casts one cosine-distributed ray drawn from `u` (in
/// `[0, 1)²`), scoring `pi L V`: an unobstructed point gets `pi L` without noise, a closed room
/// exactly 0. A map casts two rays, one by cosine (from `u`) and one by the map's luminance
/// ([`SkyMap::sample`](mcrad_scene_io::SkyMap::sample), from `v`), combined by the balance
/// heuristic: each scores `L V cos / (p_cos + p_map)`, their sum is the estimate. The mean
/// of such estimates over stratified `u` (and `v`) is what callers use.
#[allow(clippy::too_many_arguments)]
pub fn sky_irradiance_sample<C: RayCaster + ?Sized>(
    caster: &C,
    sky: &Sky,
    far: f64,
    point: Vec3,
    normal: Vec3,
    patch: u32,
    u: [f64; 2],
    v: [f64; 2],
) -> DVec3 {
    let n = normal.as_dvec3();
    let from = SurfacePoint::new(point, normal, patch);
    let open = |w: DVec3| {
        let target = (point.as_dvec3() + w * far).as_vec3();
        !caster.occluded(&from, &SurfacePoint::free(target))
    };
    let w = cosine_direction(n, u);
    match sky {
        Sky::Uniform(l) => {
            if n.dot(w) > 0.0 && open(w) {
                *l * PI
            } else {
                DVec3::ZERO
            }
        }
        Sky::Map(map) => {
            let cos = n.dot(w);
            let by_cosine = if cos > 0.0 && open(w) {
                cosine_draw_weighted(map, n, w)
            } else {
                DVec3::ZERO
            };
            by_cosine + map_draw_weighted(caster, map, far, &from, n, v)
        }
    }
}

/// The balance heuristic's score `L(w) cos / (p_cos + p_map)` (W/m²) of a cosine-drawn
/// direction `w` about unit normal `n` that reaches the sky of `map`.
pub(crate) fn cosine_draw_weighted(map: &SkyMap, n: DVec3, w: DVec3) -> DVec3 {
    let cos = n.dot(w);
    map.radiance(w) * (cos / (cos / PI + map.pdf(w)))
}

/// The balance heuristic's score `L V cos / (p_cos + p_map)` (W/m²) of a direction drawn from
/// `map` by its luminance (from `v` in `[0, 1)²`) at the surface point `from` of unit normal
/// `n`: 0 below the surface or where the ray is blocked within `far`.
pub(crate) fn map_draw_weighted<C: RayCaster + ?Sized>(
    caster: &C,
    map: &SkyMap,
    far: f64,
    from: &SurfacePoint,
    n: DVec3,
    v: [f64; 2],
) -> DVec3 {
    let Some(s) = map.sample(v) else {
        return DVec3::ZERO;
    };
    let cos = n.dot(s.direction);
    let target = (from.point.as_dvec3() + s.direction * far).as_vec3();
    if cos > 0.0 && !caster.occluded(from, &SurfacePoint::free(target)) {
        map.radiance(s.direction) * (cos / (cos / PI + s.pdf))
    } else {
        DVec3::ZERO
    }
}

/// A cosine-distributed unit direction about unit normal `n` from `u` in `[0, 1)²`.
pub(crate) fn cosine_direction(n: DVec3, u: [f64; 2]) -> DVec3 {
    let (t, b) = n.any_orthonormal_pair();
    let r = u[0].sqrt();
    let phi = TAU * u[1];
    let z = (1.0 - u[0]).max(0.0).sqrt();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * z).normalize()
}

/// `count` points of `[0, 1)²` stratified and shuffled by `rng`: a jittered `m x m` grid when
/// `count = m²`, a Latin hypercube (one point in each row and each column of `count` strata)
/// otherwise; the order is a random permutation, so any contiguous share of them is spread
/// over the square.
pub(crate) fn stratified(count: usize, rng: &mut Stream) -> Vec<[f64; 2]> {
    let m = count.isqrt();
    let mut points: Vec<[f64; 2]> = if m * m == count {
        (0..count)
            .map(|k| {
                [
                    ((k % m) as f64 + rng.uniform_f64()) / m as f64,
                    ((k / m) as f64 + rng.uniform_f64()) / m as f64,
                ]
            })
            .collect()
    } else {
        let mut columns: Vec<usize> = (0..count).collect();
        shuffle(&mut columns, rng);
        (0..count)
            .map(|k| {
                [
                    (k as f64 + rng.uniform_f64()) / count as f64,
                    (columns[k] as f64 + rng.uniform_f64()) / count as f64,
                ]
            })
            .collect()
    };
    shuffle(&mut points, rng);
    for p in &mut points {
        // rounding of `(m - 1 + u) / m` may reach 1
        p[0] = p[0].min(1.0 - f64::EPSILON);
        p[1] = p[1].min(1.0 - f64::EPSILON);
    }
    points
}

/// Fisher-Yates with `rng`.
fn shuffle<T>(items: &mut [T], rng: &mut Stream) {
    for i in (1..items.len()).rev() {
        let j = ((rng.uniform_f64() * (i + 1) as f64) as usize).min(i);
        items.swap(i, j);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stratified_points_fill_every_stratum_once() {
        let mut rng = Stream::new(3, 0, 0, 0);
        // a square count: one point per grid cell
        let p = stratified(64, &mut rng);
        let mut cells: Vec<usize> = p
            .iter()
            .map(|q| (q[0] * 8.0) as usize + 8 * (q[1] * 8.0) as usize)
            .collect();
        cells.sort_unstable();
        assert_eq!(cells, (0..64).collect::<Vec<_>>());
        // any other count: one point per row and per column
        let p = stratified(12, &mut rng);
        for axis in 0..2 {
            let mut rows: Vec<usize> = p.iter().map(|q| (q[axis] * 12.0) as usize).collect();
            rows.sort_unstable();
            assert_eq!(rows, (0..12).collect::<Vec<_>>());
        }
    }

    #[test]
    fn cosine_directions_have_the_cosine_law_mean() {
        // E[cos] = 2/3 under the cosine density; 4096 stratified points: error far below 1e-3
        let mut rng = Stream::new(5, 0, 0, 0);
        let n = DVec3::new(0.3, -0.5, 0.8).normalize();
        let p = stratified(4096, &mut rng);
        let mean = p
            .iter()
            .map(|&u| cosine_direction(n, u).dot(n))
            .sum::<f64>()
            / 4096.0;
        assert!((mean - 2.0 / 3.0).abs() < 1e-3, "{mean}");
    }
}
