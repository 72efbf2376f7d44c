//! From a hit to radiance: flat (per-patch) or smooth (per-corner, interpolated) radiosity.

use std::f64::consts::PI;

use glam::{DVec3, Vec3};
use mcrad_meshing::{CornerValues, Mesh};
use mcrad_random::Stream;
use mcrad_raycast::{Hit, RayCaster, SurfacePoint};
use mcrad_scene_io::Light;

use crate::RenderError;

/// The radiosity solution to render, in W/m² per RGB channel. A pixel shows radiance
/// `L = B / π` (W/(m² sr)) of the surface it sees (diffuse surfaces look equally bright from
/// every direction).
#[derive(Debug, Clone, Copy)]
pub enum Shading<'a> {
    /// Radiosity `B_i` per patch, in mesh order (`len = mesh.patches().len()`): each patch is
    /// drawn in one colour.
    Flat(&'a [DVec3]),
    /// Radiosity per mesh corner: entry `first(p) + k` belongs to corner `k` of patch `p`
    /// (`mesh.corners(p)[k]`), where `first(p)` is the number of corners of all patches before
    /// `p` (`len` = total corner count). A hit is shaded by linear (barycentric) interpolation
    /// over the corners of the fan triangle of its patch that contains it.
    Smooth(&'a CornerValues),
}

/// Radiance `L = B / π` (W/(m² sr)) of radiosity `b` (W/m²), in `f32`.
fn radiance(b: DVec3) -> Vec3 {
    (b / PI).as_vec3()
}

/// A [`Shading`] checked against its mesh, giving radiance (W/(m² sr), `f32`): flat, converted
/// per patch; smooth, converted per corner as it is read (a copy per corner would be 12 bytes
/// a corner beside the values).
pub(crate) enum Shader<'a> {
    Flat(Vec<Vec3>),
    Smooth(&'a CornerValues),
}

impl<'a> Shader<'a> {
    /// Checks lengths and finiteness and converts radiosity to radiance.
    pub(crate) fn new(mesh: &Mesh, shading: Shading<'a>) -> Result<Shader<'a>, RenderError> {
        let to_radiance = |values: &[DVec3]| -> Result<Vec<Vec3>, RenderError> {
            values
                .iter()
                .enumerate()
                .map(|(index, &b)| {
                    if b.is_finite() {
                        Ok(radiance(b))
                    } else {
                        Err(RenderError::NonFiniteRadiosity { index, value: b })
                    }
                })
                .collect()
        };
        match shading {
            Shading::Flat(b) => {
                let expected = mesh.patches().len();
                if b.len() != expected {
                    return Err(RenderError::ShadingLength {
                        per: "patch",
                        expected,
                        got: b.len(),
                    });
                }
                Ok(Shader::Flat(to_radiance(b)?))
            }
            Shading::Smooth(b) => {
                let expected = mesh.corner_count();
                if b.len() != expected {
                    return Err(RenderError::ShadingLength {
                        per: "corner",
                        expected,
                        got: b.len(),
                    });
                }
                match b.first_not_finite() {
                    Some((index, value)) => Err(RenderError::NonFiniteRadiosity { index, value }),
                    None => Ok(Shader::Smooth(b)),
                }
            }
        }
    }

    /// Radiance (W/(m² sr)) seen along a ray whose first hit is `hit` (`None`: a miss). Misses,
    /// back faces and ids that are no patch of `mesh` are black.
    pub(crate) fn radiance(&self, mesh: &Mesh, hit: Option<Hit>) -> Vec3 {
        let Some(hit) = hit.filter(|h| h.front) else {
            return Vec3::ZERO;
        };
        let id = hit.id as usize;
        let Some(patch) = mesh.patches().get(id) else {
            return Vec3::ZERO;
        };
        match self {
            Shader::Flat(radiance) => radiance[id],
            Shader::Smooth(b) => {
                let first = mesh.corner_offset(id);
                let radiance = |k: usize| radiance(b[first + k]);
                interpolate_with(mesh.positions(), mesh.corners(patch), radiance, hit.point)
            }
        }
    }
}

/// The radiance `E / π` (W/(m² sr)) a front hit's patch emits of its own; 0 for a miss, a back
/// face or an id that is no patch of `mesh`.
pub(crate) fn emitted_radiance(mesh: &Mesh, hit: Option<Hit>) -> DVec3 {
    hit.filter(|h| h.front)
        .and_then(|h| mesh.patches().get(h.id as usize))
        .map_or(DVec3::ZERO, |p| p.emission.as_dvec3() / PI)
}

/// The direct light of lights without a surface, drawn per sample with shadow rays.
pub(crate) struct Direct {
    /// The lights in the mesh's frame.
    lights: Vec<Light>,
    /// How far a sun's shadow ray reaches (beyond the scene).
    far: f64,
}

impl Direct {
    /// `lights` (in the scene's frame) moved into `mesh`'s frame.
    pub(crate) fn new(mesh: &Mesh, lights: &[Light]) -> Direct {
        Direct {
            lights: lights
                .iter()
                .map(|l| l.translated(-mesh.origin()))
                .collect(),
            far: mesh.escape_distance(),
        }
    }

    /// The reflected radiance `rho E(x) max(0, n · w) V / π` (W/(m² sr)) of the lights' direct
    /// light at the front hit `hit`, one shadow ray per light drawn from `rng`; 0 for a miss, a
    /// back face or no lights.
    pub(crate) fn radiance<C: RayCaster + ?Sized>(
        &self,
        mesh: &Mesh,
        caster: &C,
        hit: Option<Hit>,
        rng: &mut Stream,
    ) -> DVec3 {
        if self.lights.is_empty() {
            return DVec3::ZERO;
        }
        let Some(hit) = hit.filter(|h| h.front) else {
            return DVec3::ZERO;
        };
        let Some(patch) = mesh.patches().get(hit.id as usize) else {
            return DVec3::ZERO;
        };
        let mut h = DVec3::ZERO;
        for light in &self.lights {
            let u = [rng.uniform_f64(), rng.uniform_f64()];
            let Some((e, target)) = light.arrival(hit.point, patch.normal, u, self.far) else {
                continue;
            };
            let from = SurfacePoint::new(hit.point, patch.normal, hit.id);
            if !caster.occluded(&from, &SurfacePoint::free(target)) {
                h += e;
            }
        }
        patch.reflectance.as_dvec3() * h / PI
    }
}

/// The reflected radiance `rho H_sky / π` (W/(m² sr)) of the sky's direct light at the front
/// hit `hit`, `H_sky` the mean of [`sky_irradiance_sample`](crate::sky_irradiance_sample) over
/// the points `u[range]` (and `v[range]` for a map; `v` may be empty for a uniform sky); 0 for a
/// miss or a back face.
#[allow(clippy::too_many_arguments)]
pub(crate) fn sky_radiance<C: RayCaster + ?Sized>(
    mesh: &Mesh,
    caster: &C,
    sky: &mcrad_scene_io::Sky,
    far: f64,
    hit: Option<Hit>,
    u: &[[f64; 2]],
    v: &[[f64; 2]],
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
    let mut h = DVec3::ZERO;
    for k in range {
        let vk = v.get(k).copied().unwrap_or(u[k]);
        h += crate::sky_irradiance_sample(
            caster,
            sky,
            far,
            hit.point,
            patch.normal,
            hit.id,
            u[k],
            vk,
        );
    }
    patch.reflectance.as_dvec3() * h / (count * PI)
}

/// Linear interpolation of per-corner `values` at `point` on a convex polygon with corner
/// vertex indices `corners` (into `positions`): barycentric over the fan triangle
/// `(0, j, j + 1)` that contains the point (or, for a point just outside through rounding, the
/// one it is least outside of), with negative weights clamped to 0 and the rest renormalised.
/// This is how renders shade [`Shading::Smooth`]; bakers sample a solution the same way.
/// `values` has one entry per corner, in the units of the quantity interpolated.
pub fn interpolate(positions: &[Vec3], corners: &[u32], values: &[Vec3], point: Vec3) -> Vec3 {
    interpolate_with(positions, corners, |k| values[k], point)
}

/// [`interpolate`] with the value at corner `k` given by `value(k)`.
fn interpolate_with(
    positions: &[Vec3],
    corners: &[u32],
    value: impl Fn(usize) -> Vec3,
    point: Vec3,
) -> Vec3 {
    let a = positions[corners[0] as usize];
    let mut best: Option<(f32, usize, [f32; 3])> = None;
    for j in 1..corners.len() - 1 {
        let b = positions[corners[j] as usize];
        let c = positions[corners[j + 1] as usize];
        let Some(w) = barycentric(a, b, c, point) else {
            continue;
        };
        let score = w[0].min(w[1]).min(w[2]);
        if best.is_none_or(|(s, _, _)| score > s) {
            best = Some((score, j, w));
        }
        if score >= 0.0 {
            break;
        }
    }
    match best {
        Some((_, j, w)) => {
            let w = w.map(|x| x.max(0.0));
            let sum = w[0] + w[1] + w[2];
            (w[0] * value(0) + w[1] * value(j) + w[2] * value(j + 1)) / sum
        }
        // every fan triangle degenerate (cannot happen for a valid patch): the corner mean
        None => (0..corners.len()).map(value).sum::<Vec3>() / corners.len() as f32,
    }
}

/// Barycentric weights of `p` (projected onto the triangle's plane) for `a`, `b`, `c`; `None`
/// for a degenerate triangle.
fn barycentric(a: Vec3, b: Vec3, c: Vec3, p: Vec3) -> Option<[f32; 3]> {
    let (e1, e2, d) = (b - a, c - a, p - a);
    let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
    let (d1p, d2p) = (e1.dot(d), e2.dot(d));
    let denom = d11 * d22 - d12 * d12;
    // NaN (non-finite input) also counts as degenerate
    if denom.is_nan() || denom <= f32::EPSILON * d11 * d22 {
        return None;
    }
    let u = (d22 * d1p - d12 * d2p) / denom;
    let v = (d11 * d2p - d12 * d1p) / denom;
    Some([1.0 - u - v, u, v])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn interpolation_is_exact_for_a_linear_function_on_a_quad() {
        // a square in the xy plane, value = (x, y, x + 2y)
        let positions = [
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        let f = |p: Vec3| Vec3::new(p.x, p.y, p.x + 2.0 * p.y);
        let values: Vec<Vec3> = positions.iter().map(|&p| f(p)).collect();
        let corners = [0, 1, 2, 3];
        for p in [
            Vec3::new(0.3, 0.8, 0.0),
            Vec3::new(1.7, 0.2, 0.0),
            Vec3::new(1.0, 0.5, 0.0),
            Vec3::new(2.0, 1.0, 0.0),
        ] {
            let v = interpolate(&positions, &corners, &values, p);
            assert!((v - f(p)).length() < 1e-5, "{p}: {v}");
        }
        // slightly outside: clamped to the edge value
        let v = interpolate(&positions, &corners, &values, Vec3::new(-0.001, 0.5, 0.0));
        assert!((v - f(Vec3::new(0.0, 0.5, 0.0))).length() < 1e-3, "{v}");
    }
}
