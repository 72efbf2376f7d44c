//! The mesh's own error: how far one constant per element is from the light it stands for.
//!
//! A radiosity solution holds one value `v_p` per element `p` (its mean over the element),
//! and the transport moves light between elements as those constants. Where the light
//! varies within an element, the constant is off by the variation, pointwise by
//! `f(x) - v_p`, and the element's light passed on to others carries the same first-order
//! error (docs/atrium.md, "Where the floor is": the bias halves with the element's edge).
//!
//! The estimate compares the constant with the linear reconstruction `L_p(x)` that the
//! neighbours' values give: at each corner `k` of `p` the area-weighted mean
//! `c_k = sum_q w_kq v_q`, `w_kq = A_q / sum_q' A_q'` over the corner's group
//! ([`Mesh::corner_groups`]: the patches of the same surface at that point, `p` included),
//! interpolated linearly over each fan triangle of `p`. For a field linear over the surface,
//! `c_k` is the field's value at an interior corner (a symmetric neighbourhood), so
//! `L_p - v_p = f - f(centroid)` and the mean square
//!
//! ```text
//!   D_p² = (1 / A_p) ∫_p (L_p(x) - v_p)² dA
//! ```
//!
//! is exactly the mean-square error of the constant, `(1 / A_p) ∫_p (f - v_p)² dA`: first
//! order in the element's size (`|∇f|² I_p / A_p`, `I_p` the polar second moment of area).
//! Over one fan triangle `t` with corner differences `d_a, d_b, d_c` (`d_k = c_k - v_p`),
//! `(1 / A_t) ∫_t u² dA = ((d_a + d_b + d_c)² + d_a² + d_b² + d_c²) / 12` for the linear `u`.
//!
//! **Noise.** The values are Monte Carlo estimates with variances `s_q²`; a difference of
//! noisy values is noisy, and its square is biased up by its variance: with independent
//! errors, `d_k = sum_q a_kq v_q` (`a_kq = w_kq - [q = p]`) has
//! `E[d_k d_l] = d̄_k d̄_l + sum_q a_kq a_lq s_q²`, so
//!
//! ```text
//!   E[D_p²] = D̄_p² + N_p,
//!   N_p = sum_t (A_t / A_p) / 12 ( sum_q (sum_{k in t} a_kq)² s_q² + sum_{k in t} sum_q a_kq² s_q² ),
//! ```
//!
//! and `e_p² = max(0, D_p² - N_p)` estimates `D̄_p²` without the noise floor (unbiased
//! before the clamp at zero, which leans towards reporting more). A flat-lit surface then
//! reports about zero however noisy its values; positively correlated errors (the patches
//! of one face in some methods) make the differences less noisy than assumed, so there the
//! estimate leans low.
//!
//! Limits: at a corner on a surface's border the mean of one side's elements is not the
//! field's value there (it is off by half an element's slope), so elements along borders
//! see part of their gradient; a shadow edge or contact line inside an element shows only as
//! far as the neighbours' values see it.

use crate::build::Mesh;
use crate::smooth::CornerGroups;
use glam::DVec3;

impl Mesh {
    /// The discretization error of every patch (module docs): `e_p`, per channel in the
    /// units of `values`, the root mean square over the patch of the difference between its
    /// constant value and the linear reconstruction of its neighbours' (area-weighted means
    /// at its corners over `groups`), less the expected contribution of the values' noise
    /// when `variance` (per patch and channel, in the units of `values` squared, the errors
    /// taken as independent) is given: `e_p² = max(0, D_p² - N_p)`.
    ///
    /// `groups` is [`Mesh::corner_groups`] of this mesh (computed once, reused across calls).
    /// A field linear over a surface gives its exact root-mean-square deviation from the
    /// patch mean at patches away from the surface's border; a constant field gives 0.
    ///
    /// # Panics
    /// If `values` (or `variance`) does not hold one entry per patch, or `groups` is of
    /// another mesh.
    pub fn discretization_error(
        &self,
        values: &[DVec3],
        variance: Option<&[DVec3]>,
        groups: &CornerGroups,
    ) -> Vec<DVec3> {
        let patches = self.patches();
        assert_eq!(values.len(), patches.len(), "one value per patch");
        if let Some(v) = variance {
            assert_eq!(v.len(), patches.len(), "one variance per patch");
        }
        assert_eq!(
            groups.corner_groups().len(),
            self.corner_count(),
            "corner groups of this mesh"
        );
        let positions = self.positions();
        // per group: the area-weighted mean of its patches' values
        let mean: Vec<DVec3> = (0..groups.len())
            .map(|g| {
                let (mut sum, mut area) = (DVec3::ZERO, 0.0);
                for &q in groups.patches(g) {
                    let a = patches[q as usize].area;
                    sum += a * values[q as usize];
                    area += a;
                }
                if area > 0.0 { sum / area } else { DVec3::ZERO }
            })
            .collect();
        // per (corner, patch of its group): a_kq = w_kq - [q = p], a short list per corner
        let coefficients = |g: usize, p: usize| -> Vec<(u32, f64)> {
            let members = groups.patches(g);
            let area: f64 = members.iter().map(|&q| patches[q as usize].area).sum();
            let mut out: Vec<(u32, f64)> = members
                .iter()
                .map(|&q| {
                    let w = if area > 0.0 {
                        patches[q as usize].area / area
                    } else {
                        0.0
                    };
                    (q, w - if q as usize == p { 1.0 } else { 0.0 })
                })
                .collect();
            if !members.contains(&(p as u32)) {
                out.push((p as u32, -1.0));
            }
            out
        };
        let mut out = Vec::with_capacity(patches.len());
        for (p, patch) in patches.iter().enumerate() {
            let corners = self.corners(patch);
            let offset = self.corner_offset(p);
            let n = corners.len();
            if n < 3 {
                out.push(DVec3::ZERO);
                continue;
            }
            let group: Vec<usize> = (0..n).map(|k| groups.group_of(offset + k)).collect();
            let d: Vec<DVec3> = group.iter().map(|&g| mean[g] - values[p]).collect();
            let at = |k: usize| positions[corners[k] as usize].as_dvec3();
            let (mut square, mut noise, mut area) = (DVec3::ZERO, DVec3::ZERO, 0.0);
            let a: Option<Vec<Vec<(u32, f64)>>> =
                variance.map(|_| group.iter().map(|&g| coefficients(g, p)).collect());
            for j in 1..n - 1 {
                let t = [0, j, j + 1];
                let area_t = (at(j) - at(0)).cross(at(j + 1) - at(0)).length() / 2.0;
                if area_t <= 0.0 {
                    continue;
                }
                area += area_t;
                let sum = d[0] + d[j] + d[j + 1];
                square += area_t * (sum * sum + d[0] * d[0] + d[j] * d[j] + d[j + 1] * d[j + 1]);
                if let (Some(a), Some(s2)) = (&a, variance) {
                    // sum_q (sum_k a_kq)² s_q² + sum_k sum_q a_kq² s_q²
                    let mut merged: Vec<(u32, f64)> = Vec::new();
                    let mut own = DVec3::ZERO;
                    for &k in &t {
                        for &(q, c) in &a[k] {
                            own += c * c * s2[q as usize].max(DVec3::ZERO);
                            match merged.iter_mut().find(|(r, _)| *r == q) {
                                Some(entry) => entry.1 += c,
                                None => merged.push((q, c)),
                            }
                        }
                    }
                    let shared: DVec3 = merged
                        .iter()
                        .map(|&(q, c)| c * c * s2[q as usize].max(DVec3::ZERO))
                        .sum();
                    noise += area_t * (shared + own);
                }
            }
            if area <= 0.0 {
                out.push(DVec3::ZERO);
                continue;
            }
            let d2 = square / (12.0 * area);
            let n2 = noise / (12.0 * area);
            out.push((d2 - n2).max(DVec3::ZERO).powf(0.5));
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use crate::{DEFAULT_CREASE_ANGLE_DEGREES, Mesh, Subdivision};
    use glam::{DVec3, Vec3};
    use mcrad_scene_io::{Face, Material, Scene};

    /// A `size × size` square in the plane z = 0, cut into quads of edge at most `edge`.
    fn square(size: f32, edge: f32) -> Mesh {
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(size, 0.0, 0.0),
            Vec3::new(size, size, 0.0),
            Vec3::new(0.0, size, 0.0),
        ];
        let faces = vec![Face {
            vertices: vec![0, 1, 2, 3],
            material: 0,
            source: 0,
        }];
        let materials = vec![Material {
            name: "lamp".into(),
            reflectance: Vec3::splat(0.5),
            emission: Vec3::ONE,
        }];
        let scene = Scene::new(positions, faces, materials).expect("scene").0;
        Mesh::build(&scene, Subdivision::MaxEdge(edge)).expect("mesh")
    }

    /// Whether a patch of `mesh` touches the border of the `size` square.
    fn on_border(mesh: &Mesh, p: usize, size: f32) -> bool {
        mesh.corners(&mesh.patches()[p]).iter().any(|&v| {
            let x = mesh.positions()[v as usize];
            x.x.min(x.y) < 1e-4 || x.x.max(x.y) > size - 1e-4
        })
    }

    /// A linear ramp `f = g x`: every interior element's mean is `f` at its centroid, and
    /// the root mean square of `f - v_p` over a square element of edge `h` is `g h / sqrt(12)`
    /// (the x-variance of a uniform square). The estimate is exact there (to rounding), and
    /// border elements report between half and all of it.
    #[test]
    fn a_linear_ramp_gives_the_constants_exact_error() {
        let (size, edge, g) = (4.0, 0.5, 3.0);
        let mesh = square(size, edge);
        let values: Vec<DVec3> = mesh
            .patches()
            .iter()
            .map(|p| DVec3::splat(g * f64::from(p.centroid.x)))
            .collect();
        let groups = mesh.corner_groups(DEFAULT_CREASE_ANGLE_DEGREES);
        let e = mesh.discretization_error(&values, None, &groups);
        let exact = g * f64::from(edge) / 12f64.sqrt();
        let mut interior = 0;
        for (p, e) in e.iter().enumerate() {
            if on_border(&mesh, p, size) {
                assert!(e.x > 0.5 * exact - 1e-9 && e.x < exact + 1e-9, "{p}: {e}");
            } else {
                interior += 1;
                assert!(
                    (e.x - exact).abs() < 1e-6 * exact,
                    "{p}: {} vs {exact}",
                    e.x
                );
            }
        }
        assert_eq!(interior, 36);
    }

    /// A quadratic `f = x²` on a coarse mesh (elements of `h = 0.5`): the error of the constant
    /// per element is `sqrt(mean((x² - v_p)²))` with `v_p` the element's mean, known in closed
    /// form over `[a, a + h]`. Interior elements' estimates fall within a factor 1 to 1.2 of
    /// it: the corner means of a quadratic sit `h² / 3` above it and the element's mean
    /// `h² / 12`, so the differences carry a second-order offset `h² / 4` that adds in
    /// quadrature (1.15 at `[0.5, 1]`, where the slope is smallest against it, falling to 1.01
    /// at `[3, 3.5]`).
    #[test]
    fn a_quadratic_ramp_is_estimated_within_twenty_percent() {
        let (size, edge) = (4.0f32, 0.5f32);
        let mesh = square(size, edge);
        let h = f64::from(edge);
        // mean of x² over [a, a + h], and of x⁴
        let mean2 = |a: f64| ((a + h).powi(3) - a.powi(3)) / (3.0 * h);
        let mean4 = |a: f64| ((a + h).powi(5) - a.powi(5)) / (5.0 * h);
        let values: Vec<DVec3> = mesh
            .patches()
            .iter()
            .map(|p| DVec3::splat(mean2(f64::from(p.centroid.x) - h / 2.0)))
            .collect();
        let groups = mesh.corner_groups(DEFAULT_CREASE_ANGLE_DEGREES);
        let e = mesh.discretization_error(&values, None, &groups);
        for (p, patch) in mesh.patches().iter().enumerate() {
            if on_border(&mesh, p, size) {
                continue;
            }
            let a = f64::from(patch.centroid.x) - h / 2.0;
            let exact = (mean4(a) - mean2(a).powi(2)).sqrt();
            let ratio = e[p].x / exact;
            assert!((0.999..1.2).contains(&ratio), "{p}: {} vs {exact}", e[p].x);
        }
    }

    /// A flat-lit surface (a furnace: the same light everywhere) estimated with noise: the
    /// values are 1 plus independent errors of standard deviation `s = 0.05` (a fixed,
    /// deterministic pseudo-random sequence). Without the noise floor the differences of noisy
    /// values report a mesh error of mean square about `0.6 s²` (measured 0.63); with it,
    /// under `0.35 s²` (measured 0.27: what is left is the clamp at zero of a statistic of
    /// few degrees of freedom, unbiased before it), so the total `sqrt(noise² + mesh²)`
    /// over-reports a flat-lit surface by at most 16% in the mean square. A noiseless
    /// constant gives exactly 0.
    #[test]
    fn a_flat_lit_surface_reports_about_zero_beyond_its_noise() {
        let (size, edge) = (4.0, 0.125);
        let mesh = square(size, edge);
        let n = mesh.patches().len();
        let sd = 0.05;
        // a fixed sequence of standard normal deviates (Box-Muller over a linear
        // congruential generator): deterministic, no random streams in this crate
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut uniform = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let values: Vec<DVec3> = (0..n)
            .map(|_| {
                let (u, v) = (uniform(), uniform());
                let z = (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos();
                DVec3::splat(1.0 + sd * z)
            })
            .collect();
        let variance = vec![DVec3::splat(sd * sd); n];
        let groups = mesh.corner_groups(DEFAULT_CREASE_ANGLE_DEGREES);
        let raw = mesh.discretization_error(&values, None, &groups);
        let floored = mesh.discretization_error(&values, Some(&variance), &groups);
        let ms = |e: &[DVec3]| e.iter().map(|e| e.x * e.x).sum::<f64>() / n as f64;
        assert!(ms(&raw) > 0.5 * sd * sd, "raw {}", ms(&raw).sqrt());
        assert!(
            ms(&floored) < 0.35 * sd * sd,
            "floored {} raw {}",
            ms(&floored).sqrt(),
            ms(&raw).sqrt()
        );
        let constant = vec![DVec3::ONE; n];
        let zero = mesh.discretization_error(&constant, Some(&variance), &groups);
        assert!(zero.iter().all(|e| *e == DVec3::ZERO));
    }
}
