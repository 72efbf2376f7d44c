//! The direct irradiance of lights without a surface (point, spot, sun), deterministically:
//! what the reference solver adds as emission `rho H` (see [`direct_irradiance`]).
//!
//! For patch `i` of area `A_i` and a light, `H_i = (1/A_i) ∫_{P_i} E(x) max(0, n_i · w(x))
//! V(x) dA` (W/m²), with `E(x) w(x)` the light's irradiance at `x` on a surface facing it
//! ([`Light::sample`]) and `V` the visibility, tested at [`PROBE`] points of each patch triangle
//! (Roberts' R2 low-discrepancy sequence folded into the triangle) with one shadow ray each:
//! - every probe lit (and the light wholly in front of the patch): the unoccluded integral in
//!   closed form where one exists: an isotropic point light without a range gives
//!   `I Ω_i / A_i`, with `Ω_i` the solid angle the patch subtends at the light (since
//!   `cos θ_x dA / r² = dΩ`); a sun gives `E n_i · w` (the cone's mean cosine is divided out
//!   by [`Light::sample`]). Spot cones and range windows take the equal-weight rule on
//!   [`FINE`] R2 points per triangle (the integrand is smooth there).
//! - no probe lit: 0.
//! - some lit: the equal-weight rule with visibility on [`FINE`] R2 points per triangle, a
//!   sun's direction in its cone from another low-discrepancy sequence (`cone_u`: not a
//!   function of the point's place, which biased the penumbra). Across a straight shadow edge
//!   the error is about `2e-4` of the patch's irradiance (measured against the closed form of a
//!   half-shadowed square; a lattice rule errs by up to half a cell along axis-aligned edges).
//!
//! A shadow that falls between all [`PROBE`] points (a thin pole far from the light) is missed:
//! such a patch counts as wholly lit. Nothing is random: the answer depends on the mesh, the
//! lights and the caster only.

use glam::{DVec3, Vec3};
use mcrad_meshing::Mesh;
use mcrad_raycast::{RayCaster, SurfacePoint};
use mcrad_scene_io::{Light, Sky};
use rayon::prelude::*;

/// Points per triangle that probe the visibility.
pub const PROBE: u32 = 256;
/// Points per triangle where the light is partly hidden or has no closed form.
pub const FINE: u32 = 16_384;

/// What [`direct_irradiance`] found.
#[derive(Debug, Clone, PartialEq)]
pub struct Direct {
    /// Per patch, the mean direct irradiance from all lights, W/m² per channel (`>= 0`).
    pub irradiance: Vec<DVec3>,
    /// Shadow rays cast.
    pub rays: u64,
    /// Patch-light pairs integrated in closed form (wholly lit, no spot cone or range).
    pub exact: u64,
    /// Patch-light pairs integrated by the equal-weight rule ([`FINE`] points per triangle).
    pub quadrature: u64,
}

/// The mean direct irradiance `H_i = (1/A_i) ∫ E(x) max(0, n_i · w(x)) V(x) dA` (W/m²) of each
/// patch of `mesh` from `lights` (in the mesh's frame: translated by `-mesh.origin()`), with
/// visibility from `caster` (ids = patch indices). [`PROBE`] low-discrepancy points per
/// triangle test the visibility: a patch they find wholly lit gets the closed form where one
/// exists (a point light without a range: `I Ω_i / A_i`, `Ω_i` the solid angle the patch
/// subtends; a sun: `E n_i · w`); a partly shadowed one, or a spot or ranged light, the
/// equal-weight rule on [`FINE`] points per triangle with shadow rays (about `2e-4` of the
/// patch's irradiance across a straight shadow edge). A shadow falling between every probe
/// point is missed. Deterministic.
pub fn direct_irradiance<C: RayCaster>(mesh: &Mesh, caster: &C, lights: &[Light]) -> Direct {
    let far = mesh.escape_distance();
    let per_patch: Vec<(DVec3, u64, u64, u64)> = (0..mesh.patches().len())
        .into_par_iter()
        .map(|i| {
            let patch = &mesh.patches()[i];
            let triangles = triangles_f64(mesh, patch);
            let target = Target {
                id: i as u32,
                normal: patch.normal,
                triangles: &triangles,
                far,
            };
            let mut out = (DVec3::ZERO, 0, 0, 0);
            for light in lights {
                let (h, rays, exact) = target.irradiance(light, caster);
                out.0 += h;
                out.1 += rays;
                if exact {
                    out.2 += 1;
                } else if h != DVec3::ZERO {
                    out.3 += 1;
                }
            }
            out
        })
        .collect();
    Direct {
        irradiance: per_patch.iter().map(|p| p.0).collect(),
        rays: per_patch.iter().map(|p| p.1).sum(),
        exact: per_patch.iter().map(|p| p.2).sum(),
        quadrature: per_patch.iter().map(|p| p.3).sum(),
    }
}

/// Points per triangle of the sky's quadrature ([`sky_irradiance`]).
pub const SKY_POINTS: u32 = 256;
/// Directions per point of the sky's quadrature: a 16 x 16 grid over the cosine-weighted
/// hemisphere, shifted per point.
pub const SKY_DIRECTIONS: u32 = 256;

/// The mean direct irradiance `H_i = (1/A_i) ∫_{P_i} ∫ L_sky(w) max(0, n_i · w) V(x, w) dw dA`
/// (W/m² per channel) that `sky` gives each patch of `mesh` through the part of the sky it
/// sees, `V` = 1 where a ray from `x` along `w` leaves the scene (`caster`, ids = patch
/// indices: cut-outs and two-sided faces as the caster says). Deterministic quadrature: on
/// [`SKY_POINTS`] points per triangle, an equal-weight rule of [`SKY_DIRECTIONS`]
/// cosine-distributed directions (a 16 x 16 grid mapped to the hemisphere), `π/D` each; point
/// `j` and its grid's shift within a cell are the `j`-th point of the four-dimensional
/// Kronecker (R4) sequence.
///
/// A closed scene stays dark exactly and cheaply: each patch first probes 64 directions (an
/// 8 x 8 grid over the whole hemisphere) at every 16th point, and when no patch's probe
/// escapes every patch gets 0 without the rest. Otherwise every patch gets the whole
/// quadrature, whatever its own probe found: a patch that sees an opening only through a few
/// directions (a window far across a room, narrow in azimuth) is not taken for closed.
/// Error: within `7.8e-4 pi L` per patch and `-4.7e-4` of the power in a room lit through a
/// window in a wall (238 patches, `tests/sky.rs`: against the form factors and `pi L A_w`); `+2.5e-3` of the irradiance of a
/// floor that sees the sky through a window (one patch; against its form factor). `rays` counts
/// the rays cast; `exact` the patches that get exactly 0 (closed), `quadrature` the others.
pub fn sky_irradiance<C: RayCaster>(mesh: &Mesh, caster: &C, sky: &Sky) -> Direct {
    let far = mesh.escape_distance();
    let patch_sky = |i: usize| {
        let patch = &mesh.patches()[i];
        let triangles = triangles_f64(mesh, patch);
        PatchSky::new(i as u32, patch.normal, triangles, far)
    };
    let probes: Vec<(bool, u64)> = (0..mesh.patches().len())
        .into_par_iter()
        .map(|i| patch_sky(i).probe(caster))
        .collect();
    let probe_rays: u64 = probes.iter().map(|p| p.1).sum();
    if !probes.iter().any(|p| p.0) {
        return Direct {
            irradiance: vec![DVec3::ZERO; probes.len()],
            rays: probe_rays,
            exact: probes.len() as u64,
            quadrature: 0,
        };
    }
    let per_patch: Vec<(DVec3, u64)> = (0..mesh.patches().len())
        .into_par_iter()
        .map(|i| patch_sky(i).irradiance(sky, caster))
        .collect();
    let closed = per_patch.iter().filter(|p| p.0 == DVec3::ZERO).count() as u64;
    Direct {
        irradiance: per_patch.iter().map(|p| p.0).collect(),
        rays: probe_rays + per_patch.iter().map(|p| p.1).sum::<u64>(),
        exact: closed,
        quadrature: per_patch.len() as u64 - closed,
    }
}

/// One patch under the sky ([`sky_irradiance`]): its triangles in f64, normal, id and the
/// escape distance, with the quadrature's points and directions.
struct PatchSky {
    id: u32,
    normal: Vec3,
    /// The tangent frame of the direction grid, with the normal.
    frame: [DVec3; 3],
    triangles: Vec<[DVec3; 3]>,
    far: f64,
}

/// The quadrature's direction grid: `SKY_GRID x SKY_GRID` cells.
const SKY_GRID: u32 = SKY_DIRECTIONS.isqrt();

impl PatchSky {
    fn new(id: u32, normal: Vec3, triangles: Vec<[DVec3; 3]>, far: f64) -> Self {
        let n = normal.as_dvec3();
        let (t, b) = n.any_orthonormal_pair();
        PatchSky {
            id,
            normal,
            frame: [t, b, n],
            triangles,
            far,
        }
    }

    /// The `j`-th point of the four-dimensional Kronecker (R4) sequence: point `j` of a
    /// triangle and its direction grid's shift spread jointly, not in step.
    fn r4(j: usize) -> [f64; 4] {
        const R4: [f64; 4] = [
            0.856_674_883_854_502_9,
            0.733_891_856_627_126,
            0.628_706_721_037_808_6,
            0.538_597_257_223_610_1,
        ];
        R4.map(|a| ((j as f64 + 0.5) * a).fract().clamp(0.0, 1.0 - 1e-12))
    }

    /// Point `j` of triangle `tri`.
    fn point(tri: &[DVec3; 3], j: usize) -> DVec3 {
        let [mut u, mut v, _, _] = Self::r4(j);
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        tri[0] + (tri[1] - tri[0]) * u + (tri[2] - tri[0]) * v
    }

    /// The cosine-distributed direction of the point `(u, v)` of the unit square.
    fn direction(&self, u: f64, v: f64) -> DVec3 {
        let [t, b, n] = self.frame;
        let r = u.sqrt();
        let phi = std::f64::consts::TAU * v;
        (t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u).max(0.0).sqrt()).normalize()
    }

    /// Whether a ray from `x` along `w` leaves the scene.
    fn escapes<C: RayCaster>(&self, caster: &C, x: DVec3, w: DVec3) -> bool {
        let from = SurfacePoint::new(x.as_vec3(), self.normal, self.id);
        let to = SurfacePoint::free((x + w * self.far).as_vec3());
        !caster.occluded(&from, &to)
    }

    /// Whether any of 64 directions (an 8 x 8 grid over the whole square, shifted per point)
    /// at every 16th point escapes; and the rays cast.
    fn probe<C: RayCaster>(&self, caster: &C) -> (bool, u64) {
        let m = SKY_GRID / 2;
        let mut rays = 0;
        for tri in &self.triangles {
            for j in (0..SKY_POINTS as usize).step_by(16) {
                let x = Self::point(tri, j);
                let [_, _, s, t] = Self::r4(j);
                for a in 0..m {
                    for c in 0..m {
                        let u = (f64::from(a) + s) / f64::from(m);
                        let v = (f64::from(c) + t) / f64::from(m);
                        rays += 1;
                        if self.escapes(caster, x, self.direction(u, v)) {
                            return (true, rays);
                        }
                    }
                }
            }
        }
        (false, rays)
    }

    /// `(H, rays)`: the whole quadrature of [`sky_irradiance`].
    fn irradiance<C: RayCaster>(&self, sky: &Sky, caster: &C) -> (DVec3, u64) {
        let area: f64 = self.triangles.iter().map(triangle_area).sum();
        if area <= 0.0 {
            return (DVec3::ZERO, 0);
        }
        let m = SKY_GRID;
        let weight = std::f64::consts::PI / f64::from(m * m);
        let (mut sum, mut rays) = (DVec3::ZERO, 0u64);
        for tri in &self.triangles {
            let a_x = triangle_area(tri) / f64::from(SKY_POINTS);
            for j in 0..SKY_POINTS as usize {
                let x = Self::point(tri, j);
                let [_, _, s, t] = Self::r4(j);
                let mut h = DVec3::ZERO;
                for a in 0..m {
                    for c in 0..m {
                        let u = (f64::from(a) + s) / f64::from(m);
                        let v = (f64::from(c) + t) / f64::from(m);
                        let w = self.direction(u, v);
                        rays += 1;
                        if self.escapes(caster, x, w) {
                            h += sky.radiance(w);
                        }
                    }
                }
                sum += h * weight * a_x;
            }
        }
        (sum / area, rays)
    }
}

/// One patch as a receiver: its triangles in f64, normal and id.
struct Target<'a> {
    id: u32,
    normal: Vec3,
    triangles: &'a [[DVec3; 3]],
    far: f64,
}

impl Target<'_> {
    /// `(H, shadow rays, closed form?)` for one light.
    fn irradiance<C: RayCaster>(&self, light: &Light, caster: &C) -> (DVec3, u64, bool) {
        let area: f64 = self.triangles.iter().map(triangle_area).sum();
        if area <= 0.0 {
            return (DVec3::ZERO, 0, false);
        }
        let (lit, rays) = self.probe(light, caster);
        if lit == 0 {
            return (DVec3::ZERO, rays, false);
        }
        let all = lit == rays && self.wholly_in_front(light);
        if all && let Some(h) = self.closed_form(light, area) {
            return (h, rays, true);
        }
        let (sum, more) = self.point_rule(light, caster, FINE, !all);
        (sum / area, rays + more, false)
    }

    /// Probe points lit by `light`, and rays cast (one per point the light reaches at all).
    fn probe<C: RayCaster>(&self, light: &Light, caster: &C) -> (u64, u64) {
        let (mut lit, mut rays) = (0, 0);
        for t in self.triangles {
            for (k, (x, _)) in r2_points(t, PROBE).enumerate() {
                if let Some(s) = light.sample(x.as_vec3(), cone_u(k)) {
                    if self.normal.as_dvec3().dot(s.direction) <= 0.0 {
                        continue;
                    }
                    rays += 1;
                    if self.visible(x, &s, caster) {
                        lit += 1;
                    }
                }
            }
        }
        (lit, rays)
    }

    /// `∫ E max(0, n · w) V dA` (W per channel) by the equal-weight rule on `k` R2 points per
    /// triangle, with visibility tested when `shadows`; and the rays cast.
    fn point_rule<C: RayCaster>(
        &self,
        light: &Light,
        caster: &C,
        k: u32,
        shadows: bool,
    ) -> (DVec3, u64) {
        let n = self.normal.as_dvec3();
        let (mut sum, mut rays) = (DVec3::ZERO, 0);
        for t in self.triangles {
            for (j, (x, a)) in r2_points(t, k).enumerate() {
                let Some(s) = light.sample(x.as_vec3(), cone_u(j)) else {
                    continue;
                };
                let cos = n.dot(s.direction);
                if cos <= 0.0 {
                    continue;
                }
                if shadows {
                    rays += 1;
                    if !self.visible(x, &s, caster) {
                        continue;
                    }
                }
                sum += s.irradiance * cos * a;
            }
        }
        (sum, rays)
    }

    /// The unoccluded mean irradiance in closed form, where one exists.
    fn closed_form(&self, light: &Light, area: f64) -> Option<DVec3> {
        match light {
            Light::Point(p) if p.range.is_none() => {
                let o = p.position.as_dvec3();
                let omega: f64 = self
                    .triangles
                    .iter()
                    .map(|t| solid_angle(t.map(|v| v - o)))
                    .sum();
                Some(p.intensity * omega / area)
            }
            Light::Sun(s) => {
                let w = s.direction.as_dvec3().normalize();
                Some(s.irradiance * self.normal.as_dvec3().dot(w).max(0.0))
            }
            _ => None,
        }
    }

    /// Whether every point of the patch faces the light: a point light in front of the
    /// patch's plane, a sun whose whole cone is above the horizon.
    fn wholly_in_front(&self, light: &Light) -> bool {
        let n = self.normal.as_dvec3();
        match light {
            Light::Point(p) => self.in_front(n, p.position.as_dvec3()),
            Light::Spot(s) => self.in_front(n, s.point.position.as_dvec3()),
            Light::Sun(s) => {
                let w = s.direction.as_dvec3().normalize();
                n.dot(w) > (0.5 * s.diameter).sin()
            }
        }
    }

    fn in_front(&self, n: DVec3, light: DVec3) -> bool {
        self.triangles
            .iter()
            .flatten()
            .all(|v| n.dot(light - *v) > 0.0)
    }

    fn visible<C: RayCaster>(&self, x: DVec3, s: &mcrad_scene_io::LightSample, caster: &C) -> bool {
        let reach = if s.distance.is_finite() {
            s.distance
        } else {
            self.far
        };
        let to = (x + s.direction * reach).as_vec3();
        let from = SurfacePoint::new(x.as_vec3(), self.normal, self.id);
        !caster.occluded(&from, &SurfacePoint::free(to))
    }
}

/// `n` points of `t` (Roberts' R2 sequence in the unit square, folded into the triangle) with
/// equal weights `area / n`, in a fixed order.
fn r2_points(t: &[DVec3; 3], n: u32) -> impl Iterator<Item = (DVec3, f64)> + '_ {
    let weight = triangle_area(t) / f64::from(n);
    let (e1, e2) = (t[1] - t[0], t[2] - t[0]);
    (0..n as usize).map(move |j| {
        let [mut u, mut v] = r2(j);
        if u + v > 1.0 {
            (u, v) = (1.0 - u, 1.0 - v);
        }
        (t[0] + e1 * u + e2 * v, weight)
    })
}

/// The `k`-th point of Roberts' R2 sequence in `[0, 1)²`: where probe and quadrature points
/// are taken.
fn r2(k: usize) -> [f64; 2] {
    const A: [f64; 2] = [0.754_877_666_246_692_7, 0.569_840_290_998_053_2];
    let k = k as f64 + 0.5;
    A.map(|a| (k * a).fract().clamp(0.0, 1.0 - 1e-12))
}

/// Where point `k`'s direction in a sun's cone is taken (the light's sample `u`): the `k`-th
/// point of the Kronecker sequence of the last two generators of R4, so that the direction is
/// not a function of the point's place in its triangle. Drawn from [`r2`] as the point is, the
/// direction followed the point: near a shadow edge the points on one side all saw the sun's
/// disc from one side, and the penumbra's integral was off by a share of it (a sun through a
/// window onto a floor: `-1.9e-3` of the power against `E A_w cos` on patches of 0.5 m,
/// `-5.7e-4` on patches of 0.25 m; now `+8.3e-5`, `tests/window.rs`).
fn cone_u(k: usize) -> [f64; 2] {
    const A: [f64; 2] = [0.628_706_721_037_808_6, 0.538_597_257_223_610_1];
    let k = k as f64 + 0.5;
    A.map(|a| (k * a).fract().clamp(0.0, 1.0 - 1e-12))
}

/// The solid angle (sr) a triangle with corners `r` (relative to the viewpoint) subtends, by
/// Van Oosterom and Strackee's formula.
fn solid_angle(r: [DVec3; 3]) -> f64 {
    let l = r.map(|v| v.length());
    let numerator = r[0].dot(r[1].cross(r[2])).abs();
    let denominator =
        l[0] * l[1] * l[2] + r[0].dot(r[1]) * l[2] + r[0].dot(r[2]) * l[1] + r[1].dot(r[2]) * l[0];
    2.0 * numerator.atan2(denominator)
}

fn triangle_area(t: &[DVec3; 3]) -> f64 {
    0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()
}

/// The triangles of `patch` (its fan, in the mesh's local frame) with `f64` corners.
fn triangles_f64(mesh: &Mesh, patch: &mcrad_meshing::Patch) -> Vec<[DVec3; 3]> {
    let positions = mesh.positions();
    mesh.patch_triangles(patch)
        .iter()
        .map(|t| t.map(|v| positions[v as usize].as_dvec3()))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn r2_points_lie_in_the_triangle_and_weigh_its_area() {
        let t = [DVec3::ZERO, DVec3::X * 2.0, DVec3::Y * 3.0];
        let points: Vec<_> = r2_points(&t, 4096).collect();
        assert_eq!(points.len(), 4096);
        let area: f64 = points.iter().map(|p| p.1).sum();
        assert!((area - 3.0).abs() < 1e-12);
        for (p, _) in &points {
            assert!(p.x >= 0.0 && p.y >= 0.0 && p.x / 2.0 + p.y / 3.0 <= 1.0 + 1e-12);
        }
        let centroid = points.iter().map(|p| p.0 * p.1).sum::<DVec3>() / area;
        assert!((centroid - DVec3::new(2.0 / 3.0, 1.0, 0.0)).length() < 1e-3);
    }

    #[test]
    fn the_solid_angle_of_a_cube_face_is_a_sixth_of_the_sphere() {
        // A face of the cube [-1, 1]³ seen from its centre, as two triangles.
        let c = [
            DVec3::new(-1.0, -1.0, 1.0),
            DVec3::new(1.0, -1.0, 1.0),
            DVec3::new(1.0, 1.0, 1.0),
            DVec3::new(-1.0, 1.0, 1.0),
        ];
        let omega = solid_angle([c[0], c[1], c[2]]) + solid_angle([c[0], c[2], c[3]]);
        assert!((omega - 4.0 * std::f64::consts::PI / 6.0).abs() < 1e-12);
    }
}
