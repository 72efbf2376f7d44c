//! The final gather: the light arriving at a pixel's surface point, gathered with rays that
//! read the solution where they land, so that the pixel shows the light at its own point
//! rather than the mesh's reconstruction of it.

use std::f64::consts::PI;

use glam::DVec3;
use mcrad_meshing::Mesh;
use mcrad_raycast::{Hit, Ray, RayCaster, SurfacePoint};
use mcrad_scene_io::Sky;

use crate::shade::Shader;
use crate::sky::{cosine_direction, cosine_draw_weighted, map_draw_weighted};

/// The reflected radiance `rho H(x) / π` (W/(m² sr)) of the light arriving at the front hit
/// `hit` from the rest of the scene and the sky, `H(x)` estimated by cosine-distributed rays
/// drawn from the points `u[range]` of `[0, 1)²`: `H ≈ π mean_k L(w_k)`, where `L(w)` is the radiance
/// the ray along `w` meets first: the shading's radiance at a front hit (`shader`, as a camera
/// ray would see it: the solution's reflected part `(B - E) / π`, since [`Emitters`] draw the
/// emitting faces' own light), 0 at a back face, the sky's radiance (0 without a sky) where it
/// leaves the scene; a sky map is drawn by its luminance as well (from the points `v[range]`
/// one each: one more ray towards the sky, reaching `far`), the two draws combined by the balance
/// heuristic as in [`sky_irradiance_sample`](crate::sky_irradiance_sample). Lights without a
/// surface are not in it ([`Direct`](crate::shade::Direct) draws them). 0 for a miss, a back
/// face or no points.
#[allow(clippy::too_many_arguments)]
pub(crate) fn gathered_radiance<C: RayCaster + ?Sized>(
    mesh: &Mesh,
    caster: &C,
    shader: &Shader<'_>,
    sky: Option<&Sky>,
    far: f64,
    hit: Option<Hit>,
    (u, v): (&[[f64; 2]], &[[f64; 2]]),
    range: std::ops::Range<usize>,
) -> DVec3 {
    let Some(hit) = hit.filter(|h| h.front) else {
        return DVec3::ZERO;
    };
    let Some(patch) = mesh.patches().get(hit.id as usize) else {
        return DVec3::ZERO;
    };
    if range.is_empty() {
        return DVec3::ZERO;
    }
    let count = range.len() as f64;
    let n = patch.normal.as_dvec3();
    let from = SurfacePoint::new(hit.point, patch.normal, hit.id);
    let mut sum = DVec3::ZERO;
    for k in range {
        let w = cosine_direction(n, u[k]);
        let ray = Ray::from_surface(hit.point, patch.normal, w.as_vec3(), hit.id);
        sum += match (caster.closest_hit(&ray), sky) {
            // a map's bright spots are drawn by the map too: the balance heuristic's weight
            // on the cosine draw, `L cos / (p_cos + p_map)` as irradiance, over π as radiance
            (None, Some(Sky::Map(map))) => cosine_draw_weighted(map, n, w) / PI,
            (None, Some(sky)) => sky.radiance(w),
            (None, None) => DVec3::ZERO,
            (seen, _) => shader.radiance(mesh, seen).as_dvec3(),
        };
        // the map's own draw, weighted alike, where it reaches the sky
        if let (Some(Sky::Map(map)), Some(&vk)) = (sky, v.get(k)) {
            sum += map_draw_weighted(caster, map, far, &from, n, vk) / PI;
        }
    }
    // rho H / π with H = π mean L
    patch.reflectance.as_dvec3() * sum / count
}

/// The patches that emit, drawn for the final gather's direct light by their power: patch `i`
/// with probability `P_i = lum(E_i) A_i / sum_j lum(E_j) A_j` (`lum` the luminance weights),
/// then a point uniformly on it.
pub(crate) struct Emitters {
    /// The emitting patches' indices, in mesh order.
    ids: Vec<u32>,
    /// `cdf[k] = sum_{j <= k} P_j` over `ids` (the last is 1).
    cdf: Vec<f64>,
    /// `P_k` itself (a difference of the sums would lose a small emitter's digits).
    probability: Vec<f64>,
}

impl Emitters {
    /// Every patch of `mesh` whose emission has a positive luminance.
    pub(crate) fn new(mesh: &Mesh) -> Emitters {
        let power =
            |p: &mcrad_meshing::Patch| f64::from(crate::luminance(p.emission)).max(0.0) * p.area;
        let (mut ids, mut cdf, mut probability) = (Vec::new(), Vec::new(), Vec::new());
        let mut total = 0.0;
        for (i, p) in mesh.patches().iter().enumerate() {
            let w = power(p);
            if w > 0.0 && w.is_finite() {
                total += w;
                ids.push(i as u32);
                cdf.push(total);
                probability.push(w);
            }
        }
        for (c, p) in cdf.iter_mut().zip(&mut probability) {
            *c /= total;
            *p /= total;
        }
        Emitters {
            ids,
            cdf,
            probability,
        }
    }

    /// No emitters.
    pub(crate) fn empty() -> Emitters {
        Emitters {
            ids: Vec::new(),
            cdf: Vec::new(),
            probability: Vec::new(),
        }
    }

    /// Whether no patch emits.
    pub(crate) fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }

    /// The reflected radiance `rho H_e(x) / π` (W/(m² sr)) of the emitting patches' direct
    /// light at the front hit `hit`, `H_e` estimated by `count` points drawn from `rng`:
    /// a patch `i` by [`Emitters`]' probabilities, a point `y` uniformly on it, scoring
    /// `E_i / π cos_x cos_y / r² V(x, y) A_i / P_i`. 0 for a miss, a back face or no emitters.
    pub(crate) fn radiance<C: RayCaster + ?Sized>(
        &self,
        mesh: &Mesh,
        caster: &C,
        hit: Option<Hit>,
        count: usize,
        rng: &mut mcrad_random::Stream,
    ) -> DVec3 {
        let Some(hit) = hit.filter(|h| h.front) else {
            return DVec3::ZERO;
        };
        let Some(patch) = mesh.patches().get(hit.id as usize) else {
            return DVec3::ZERO;
        };
        if self.is_empty() || count == 0 {
            return DVec3::ZERO;
        }
        let (x, n) = (hit.point.as_dvec3(), patch.normal.as_dvec3());
        let from = SurfacePoint::new(hit.point, patch.normal, hit.id);
        let mut h = DVec3::ZERO;
        for _ in 0..count {
            let pick = rng.uniform_f64();
            let k = self
                .cdf
                .partition_point(|&c| c <= pick)
                .min(self.ids.len() - 1);
            let probability = self.probability[k];
            let id = self.ids[k];
            let light = &mesh.patches()[id as usize];
            let y = point_on(mesh, light, [rng.uniform_f64(), rng.uniform_f64()]);
            let d = y - x;
            let r2 = d.length_squared();
            if r2 <= 0.0 || probability <= 0.0 {
                continue;
            }
            let w = d / r2.sqrt();
            let (cos_x, cos_y) = (n.dot(w), -light.normal.as_dvec3().dot(w));
            if cos_x <= 0.0 || cos_y <= 0.0 {
                continue;
            }
            let to = SurfacePoint::new(y.as_vec3(), light.normal, id);
            if caster.occluded(&from, &to) {
                continue;
            }
            h += light.emission.as_dvec3() / PI * (cos_x * cos_y / r2 * light.area / probability);
        }
        patch.reflectance.as_dvec3() * h / (count as f64 * PI)
    }
}

/// A point of patch `patch` (a convex polygon) drawn uniformly by area from `u` in `[0, 1)²`:
/// a fan triangle `(0, j, j + 1)` by its area, then a point on it.
pub(crate) fn point_on(mesh: &Mesh, patch: &mcrad_meshing::Patch, u: [f64; 2]) -> DVec3 {
    let positions = mesh.positions();
    let corners = mesh.corners(patch);
    let at = |k: usize| positions[corners[k] as usize].as_dvec3();
    let a = at(0);
    let area = |j: usize| (at(j) - a).cross(at(j + 1) - a).length();
    let total: f64 = (1..corners.len() - 1).map(area).sum();
    // the triangle, and `u[0]` rescaled within its share
    let (mut j, mut s) = (1, u[0] * total);
    while j + 2 < corners.len() && s >= area(j) {
        s -= area(j);
        j += 1;
    }
    let t = if area(j) > 0.0 {
        (s / area(j)).clamp(0.0, 1.0)
    } else {
        0.5
    };
    let r = t.sqrt();
    let (b, c) = (at(j), at(j + 1));
    a * (1.0 - r) + b * (r * (1.0 - u[1])) + c * (r * u[1])
}
