//! The closure report: where the emitted power went, and whether the answer accounts for it.
//!
//! Every watt a scene emits is, in the end, absorbed by a surface or leaves the scene through
//! an opening. Per RGB channel, with `A_i` the area (m²), `E_i` the emitted radiosity, `B_i`
//! the answer's radiosity (W/m²) and `rho_i` the reflectance of patch `i`:
//!
//! ```text
//! emitted   = sum_i A_i E_i  +  sum_{i: rho_i > 0} A_i D_i                (exact, estimated)
//! absorbed  = sum_{i: rho_i > 0} A_i (1 - rho_i) / rho_i (B_i - E_i)  +  sum_i A_i B_i g_i
//! escaped   = sum_i A_i B_i e_i
//! balance   = emitted - absorbed - escaped                                (0 in expectation)
//! ```
//!
//! `D_i` is the mean irradiance that lights without a surface (point, spot, sun) and the sky
//! give patch `i` directly (the sky's by one cosine-distributed ray per point: `pi L(w)` where
//! it leaves the scene): their power enters the scene where it lands (light that misses the scene is
//! not counted, and light landing on a patch that reflects nothing in a channel enters and is
//! absorbed there at once, so it is left out of both). The probe estimates it with its own
//! shadow rays (one per probe ray of the patch and light, from uniform points), independent of
//! the answer; its variance adds to the balance's.
//!
//! The first term of `absorbed` is the light absorbed on the front of the patches that reflect:
//! `B_i - E_i = rho_i H_i` is the reflected part of the radiosity, `H_i` the incident
//! irradiance, and `A_i (1 - rho_i) H_i` the power absorbed. A patch that reflects nothing in
//! a channel (`rho_i = 0`) keeps no trace of its incident light in `B_i`, nor does the back of
//! a face (a ray that reaches a back face is absorbed there). That light, and the light that
//! escapes, is measured from where it leaves: `e_i` is the fraction of patch `i`'s
//! cosine-distributed rays (from uniform points) that hit nothing, `g_i` (per channel) the
//! fraction that first hit a back face or the front of a patch with `rho = 0` in the channel.
//! Power leaving patch `i` is `A_i B_i`, and it goes where its cosine rays go, so
//! `A_i B_i e_i` escapes through patch `i`'s openings and `A_i B_i g_i` dies on those sinks.
//!
//! **The probe.** `e_i` and `g_i` are estimated by `k_i` rays of patch `i` from their own
//! random streams, independent of the answer, so `B_i ê_i` is unbiased for `E[B_i] e_i`. The
//! probe casts a sixteenth of the method's rays (at least 2 per patch): 2 per patch, the rest
//! shared in proportion to the power `A_i B_i` each patch sends out (the `k_i` depend on the
//! answer but not on the probe's rays, so `ê_i` stays unbiased given them). Its rays are cast
//! after the run and not taken from the run's budget (the answer does not depend on them); they
//! are reported in [`Closure::rays`].
//!
//! **The standard error.** The balance is linear in each `B_i` with coefficient
//! `c_i = -A_i ((1 - rho_i) / rho_i + ŝ_i)` (the first term only where `rho_i > 0`),
//! `ŝ_i = ê_i + ĝ_i`; with `V_i` the reported variance of `B_i`, the probe's fractions
//! binomial and independent of the answer,
//!
//! ```text
//! Var(balance) = sum_i c_i² V_i + sum_i A_i² B_i² ŝ_i (1 - ŝ_i) / (k_i - 1)      (W²)
//! ```
//!
//! taking the patches' errors as independent: the reported variances carry no correlation
//! between patches, but for the faces of a pooled cluster ([`crate::clusters`]), which share
//! one estimate of irradiance: their errors are one error scaled, `sqrt(V_i)` each, so their
//! terms `c_i sqrt(V_i)` are summed before squaring (on the sun- and sky-lit atrium a small
//! part: 0.5% of the variance at 2e6 rays, the lights' delivery and the probe's fractions
//! being most of it). Measured over 8-16 seeds at 2e6 rays on the Cornell box (open front),
//! the mean `z²` of the balance is 0.5-0.8 on a uniform mesh of 943 patches (the standard error
//! is honest, a little large), but 2.2-3.3 on the default adaptive mesh of about 5 700
//! (`combined`, `prr`, `bidirectional`), and still 1.7-2.1 for `combined` run on that mesh
//! without the refinement's pooling (12 seeds). The many small patches of a face gather from
//! one shooting solution, and the children of a split start from their parent's estimate:
//! errors shared between patches that the per-patch variances do not carry (issue 36, item 3).
//! There the standard error is 1.3-1.8x too small and a sound run may warn, a few times in a
//! hundred. Taking the errors within an input face as fully correlated instead (an upper bound)
//! gave mean `z²` 0.04-0.15 on the adaptive mesh and 0.001 on the furnace: a check that would
//! pass nearly anything. Variances per face that carry the correlation belong here once the
//! methods report them.
//!
//! A method whose answer has no variance (`shoot`, `gather`, `two-pass`,
//! `two-pass-split`, `reference`) gets the balance without a standard error, and no check.
//!
//! **The check.** A channel whose `|balance|` exceeds [`CLOSURE_SIGMAS`] standard errors
//! (plus `1e-9` of the emitted power, for rounding) is a warning in
//! [`Answer::warnings`](crate::Answer::warnings): the answer loses or makes light beyond
//! its error bars (a bias, or error bars too small).

use crate::clusters::ALONE;
use glam::DVec3;
use mcrad_combine::Estimate;
use mcrad_mc_radiosity::{RayFates, ray_fates};
use mcrad_meshing::Mesh;
use mcrad_random::derive_seed;
use mcrad_raycast::{RayCaster, SurfacePoint};
use mcrad_scene_io::Light;
use serde::Serialize;

/// Standard errors of the balance beyond which a run warns.
pub const CLOSURE_SIGMAS: f64 = 4.0;

/// The tag of the probe's random streams (derived from the run's seed: see
/// [`mcrad_random::derive_seed`]), distinct from every method's.
const PROBE_TAG: u64 = 0x0063_6c6f_7375_7265; // "closure" in ASCII
/// The tag of the probe's shadow-ray streams towards the lights.
const LIGHT_TAG: u64 = 0x0063_6c6f_7375_7266;

/// Where a run's emitted power went, per RGB channel (W), and whether it balances (see the
/// module's maths in the crate source, `closure.rs`). Written under `"closure"` in `--stats`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Closure {
    /// Power emitted, `sum_i A_i E_i` (W; exact).
    pub emitted: [f64; 3],
    /// Power absorbed: on the front of reflecting patches, from the answer,
    /// `sum A_i (1 - rho_i) / rho_i (B_i - E_i)`, plus what the probe sees reach back faces and
    /// patches of `rho = 0` (W).
    pub absorbed: [f64; 3],
    /// Power that leaves the scene: `sum_i A_i B_i e_i`, `e_i` the probe's fraction of patch
    /// `i`'s rays that hit nothing (W; 0 in a closed scene).
    pub escaped: [f64; 3],
    /// `emitted - absorbed - escaped` (W): 0 in expectation.
    pub balance: [f64; 3],
    /// The standard error of `balance` (W); `None` (`null`) when the answer has no variance.
    pub balance_se: Option<[f64; 3]>,
    /// Rays the probe cast (not counted in the run's `rays`).
    pub rays: u64,
}

impl Closure {
    /// The balance in standard errors per channel; `None` without a standard error. A zero
    /// standard error gives 0 for a balance within rounding and infinity beyond it.
    pub fn sigmas(&self) -> Option<[f64; 3]> {
        let se = self.balance_se?;
        Some(std::array::from_fn(|c| {
            let b = self.balance[c];
            if b.abs() <= rounding(self.emitted[c]) {
                0.0
            } else {
                b.abs() / se[c]
            }
        }))
    }

    /// The warning when a channel's balance is off by more than [`CLOSURE_SIGMAS`] standard
    /// errors, one line naming the channels and the powers; `None` when it balances.
    pub fn warning(&self) -> Option<String> {
        let sigmas = self.sigmas()?;
        let se = self.balance_se?;
        let off: Vec<String> = ["red", "green", "blue"]
            .iter()
            .enumerate()
            .filter(|&(c, _)| {
                sigmas[c] > CLOSURE_SIGMAS
                    && self.balance[c].abs() > CLOSURE_SIGMAS * se[c] + rounding(self.emitted[c])
            })
            .map(|(c, name)| {
                format!(
                    "{name}: emitted {:.6e} W, absorbed {:.6e} W, escaped {:.6e} W, balance \
                     {:+.3e} ± {:.3e} W ({:.1} standard errors)",
                    self.emitted[c],
                    self.absorbed[c],
                    self.escaped[c],
                    self.balance[c],
                    se[c],
                    sigmas[c]
                )
            })
            .collect();
        (!off.is_empty()).then(|| {
            format!(
                "the answer does not conserve power within {CLOSURE_SIGMAS} standard errors \
                 (biased, or its error bars are too small): {}",
                off.join("; ")
            )
        })
    }
}

/// The balance a float sum may miss by: `1e-9` of the emitted power (W).
fn rounding(emitted: f64) -> f64 {
    1e-9 * emitted.abs()
}

/// The probe's rays for a run whose method cast `method_rays` rays on `patches` patches:
/// `method_rays /` [`PROBE_SHARE`], and at least [`MIN_PROBE_RAYS`] per patch.
pub(crate) fn probe_budget(method_rays: u64, patches: usize) -> u64 {
    (method_rays / PROBE_SHARE).max(MIN_PROBE_RAYS as u64 * patches as u64)
}

/// The probe casts one ray per this many of the method's (at least [`MIN_PROBE_RAYS`] a
/// patch).
pub(crate) const PROBE_SHARE: u64 = 16;

/// The fewest probe rays a patch gets (two give a sample variance).
const MIN_PROBE_RAYS: u32 = 2;

/// The probe's rays per patch: [`MIN_PROBE_RAYS`] each, and the rest of `budget` shared in
/// proportion to the power `A_i B_i` (channels summed) each patch sends out, where the error
/// of `A_i B_i s_i` is largest (floored: at most `budget` rays in all).
pub(crate) fn allocate(mesh: &Mesh, radiosity: &[DVec3], budget: u64) -> Vec<u32> {
    let patches = mesh.patches();
    let power: Vec<f64> = patches
        .iter()
        .zip(radiosity)
        .map(|(p, b)| (p.area * b.element_sum()).max(0.0))
        .collect();
    let total: f64 = power.iter().sum();
    let spare = budget.saturating_sub(MIN_PROBE_RAYS as u64 * patches.len() as u64) as f64;
    power
        .iter()
        .map(|&w| {
            let extra = if total > 0.0 {
                (spare * w / total).floor()
            } else {
                0.0
            };
            MIN_PROBE_RAYS.saturating_add(extra.min(f64::from(u32::MAX - MIN_PROBE_RAYS)) as u32)
        })
        .collect()
}

/// What the probe's rays saw, per patch.
pub(crate) type Probe = RayFates;

/// Casts `rays[i]` (`>= 2`) cosine-distributed rays from uniform points of each patch `i`, on
/// the closure's own streams (from `seed`): deterministic on any thread count.
pub(crate) fn probe<C: RayCaster>(mesh: &Mesh, caster: &C, rays: Vec<u32>, seed: u64) -> Probe {
    ray_fates(mesh, caster, rays, derive_seed(seed, PROBE_TAG))
}

/// The power the lights without a surface and the sky deliver to the patches that reflect, as
/// the probe estimates it (see the module's maths).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(crate) struct Delivery {
    /// `sum_{i: rho_i > 0} A_i D_i` per channel (W), `D_i` the mean direct irradiance of
    /// patch `i` over its probe points.
    pub power: DVec3,
    /// The variance of `power` (W²): `sum_{i: rho_i > 0} A_i² Var(D_i)`, the patches' points
    /// independent.
    pub variance: DVec3,
}

impl std::ops::Add for Delivery {
    type Output = Delivery;
    fn add(self, other: Delivery) -> Delivery {
        Delivery {
            power: self.power + other.power,
            variance: self.variance + other.variance,
        }
    }
}

/// Patches per block of [`light_delivery`]'s sums: blocks are summed in order, so the sums do
/// not depend on the thread count.
const DELIVERY_BLOCK: usize = 4096;

/// The [`Delivery`] of `lights` (the scene's frame) and `sky`: per patch `i` the mean direct
/// irradiance `D_i` and its variance (W/m² and (W/m²)² per channel) from `rays[i]` (at least 2)
/// uniform points, one shadow ray each per light and one cosine ray for the sky, on the
/// closure's own streams (from `seed`), summed over the patches (by blocks of
/// [`DELIVERY_BLOCK`]: no per-patch array, at 10^7 patches it was 480 MB).
pub(crate) fn light_delivery<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    lights: &[Light],
    sky: Option<&mcrad_scene_io::Sky>,
    rays: &[u32],
    seed: u64,
) -> Delivery {
    use rayon::prelude::*;
    if lights.is_empty() && sky.is_none() {
        return Delivery::default();
    }
    let lights: Vec<Light> = lights
        .iter()
        .map(|l| l.translated(-mesh.origin()))
        .collect();
    let positions = mesh.positions();
    let far = mesh.escape_distance();
    let seed = derive_seed(seed, LIGHT_TAG);
    // patch `i`'s part; `triangles` and `areas` are room reused from patch to patch
    let patch_delivery = |i: usize, (triangles, areas): &mut (Vec<[DVec3; 3]>, Vec<f64>)| {
        let patch = &mesh.patches()[i];
        triangles.clear();
        triangles.extend(
            mesh.patch_triangles(patch)
                .iter()
                .map(|t| t.map(|v| positions[v as usize].as_dvec3())),
        );
        areas.clear();
        areas.extend(
            triangles
                .iter()
                .map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()),
        );
        let total: f64 = areas.iter().sum();
        let n = rays[i].max(2);
        let mut rng = mcrad_random::Stream::new(seed, 0, i as u64, 0);
        let normal = patch.normal.as_dvec3();
        let (mut sum, mut sum2) = (DVec3::ZERO, DVec3::ZERO);
        for _ in 0..n {
            let mut pick = rng.uniform_f64() * total;
            let t = areas
                .iter()
                .position(|&a| {
                    pick -= a;
                    pick < 0.0
                })
                .unwrap_or(areas.len() - 1);
            let (r1, r2) = (rng.uniform_f64().sqrt(), rng.uniform_f64());
            let [a, b, c] = triangles[t];
            let x = a * (1.0 - r1) + b * (r1 * (1.0 - r2)) + c * (r1 * r2);
            let mut h = DVec3::ZERO;
            if let Some(sky) = sky {
                let w = cosine_direction(normal, [rng.uniform_f64(), rng.uniform_f64()]);
                let ray = mcrad_raycast::Ray::from_surface(
                    x.as_vec3(),
                    patch.normal,
                    w.as_vec3(),
                    i as u32,
                );
                if caster.closest_hit(&ray).is_none() {
                    h += sky.radiance(w) * std::f64::consts::PI;
                }
            }
            for light in &lights {
                let u = [rng.uniform_f64(), rng.uniform_f64()];
                let Some((e, to)) = light.arrival(x.as_vec3(), patch.normal, u, far) else {
                    continue;
                };
                let from = SurfacePoint::new(x.as_vec3(), patch.normal, i as u32);
                if !caster.occluded(&from, &SurfacePoint::free(to)) {
                    h += e;
                }
            }
            sum += h;
            sum2 += h * h;
        }
        let k = f64::from(n);
        let mean = sum / k;
        let var = ((sum2 - sum * mean) / (k - 1.0)).max(DVec3::ZERO) / k;
        // the lights' power enters where a channel reflects
        let reflects = DVec3::from(
            patch
                .reflectance
                .to_array()
                .map(|r| f64::from(u8::from(r > 0.0))),
        );
        let area = patch.area;
        Delivery {
            power: area * reflects * mean,
            variance: area * area * reflects * var,
        }
    };
    let patches = mesh.patches().len();
    let blocks: Vec<Delivery> = (0..patches.div_ceil(DELIVERY_BLOCK))
        .into_par_iter()
        .map(|b| {
            let mut room = (Vec::new(), Vec::new());
            let end = ((b + 1) * DELIVERY_BLOCK).min(patches);
            (b * DELIVERY_BLOCK..end)
                .map(|i| patch_delivery(i, &mut room))
                .fold(Delivery::default(), |a, b| a + b)
        })
        .collect();
    blocks.into_iter().fold(Delivery::default(), |a, b| a + b)
}

/// A cosine-distributed unit direction about the unit `n` from `u` in `[0, 1)²`.
fn cosine_direction(n: DVec3, u: [f64; 2]) -> DVec3 {
    let r = u[0].sqrt();
    let phi = std::f64::consts::TAU * u[1];
    let (t, b) = n.any_orthonormal_pair();
    (t * (r * phi.cos()) + b * (r * phi.sin()) + n * (1.0 - u[0]).max(0.0).sqrt()).normalize()
}

/// The closure of `estimate` (radiosity W/m² and variance per patch of `mesh`) with what the
/// probe saw and the power the lights delivered ([`light_delivery`]; the maths in the module
/// documentation).
pub(crate) fn closure(
    mesh: &Mesh,
    estimate: &Estimate,
    probe: &Probe,
    light: &Delivery,
    groups: &[u32],
) -> Closure {
    let variance = estimate.variance();
    let (mut emitted, mut absorbed, mut escaped, mut var) =
        (DVec3::ZERO, DVec3::ZERO, DVec3::ZERO, DVec3::ZERO);
    // per group of pooled patches, `sum c_i sqrt(V_i)`: their errors are one error scaled
    let mut shared: Vec<DVec3> = Vec::new();
    for (i, p) in mesh.patches().iter().enumerate() {
        let (area, e, rho) = (p.area, p.emission.as_dvec3(), p.reflectance.as_dvec3());
        let b = estimate.radiosity()[i];
        let k = f64::from(probe.rays[i]);
        let esc = f64::from(probe.escaped[i]) / k;
        let sunk = DVec3::from(probe.sunk[i].map(f64::from)) / k;
        let s = sunk + DVec3::splat(esc);
        // (1 - rho) / rho where the patch reflects; 0 where it does not
        let a = DVec3::from(
            rho.to_array()
                .map(|r| if r > 0.0 { (1.0 - r) / r } else { 0.0 }),
        );
        emitted += area * e;
        absorbed += area * (a * (b - e) + b * sunk);
        escaped += area * b * esc;
        if let Some(v) = variance {
            let c = area * (a + s);
            match groups.get(i).copied().filter(|&g| g != ALONE) {
                Some(g) => {
                    let g = g as usize;
                    if shared.len() <= g {
                        shared.resize(g + 1, DVec3::ZERO);
                    }
                    shared[g] += c * v[i].max(DVec3::ZERO).map(f64::sqrt);
                }
                None => var += c * c * v[i],
            }
            var += area * area * b * b * s * (DVec3::ONE - s) / (k - 1.0);
        }
    }
    var += shared.iter().map(|&x| x * x).sum::<DVec3>();
    emitted += light.power;
    var += light.variance;
    let balance = emitted - absorbed - escaped;
    Closure {
        emitted: emitted.to_array(),
        absorbed: absorbed.to_array(),
        escaped: escaped.to_array(),
        balance: balance.to_array(),
        balance_se: variance.map(|_| var.max(DVec3::ZERO).to_array().map(f64::sqrt)),
        rays: probe.rays.iter().map(|&k| u64::from(k)).sum(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::{Problem, solve};
    use std::ops::ControlFlow;

    /// A biased answer (every radiosity 10% high) on the closed furnace (`E = 1` W/m²,
    /// `rho = 0.5`) is flagged; the answer itself is not. Fixed seed; the honest answer's
    /// balance is within 4 standard errors (a false failure about 1 in 15 000 for normal errors).
    #[test]
    fn a_biased_answer_is_flagged_and_the_honest_one_is_not() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/furnace.obj");
        let scene = mcrad_scene_io::load(&path).unwrap().scene;
        let mut problem = Problem::new(&scene);
        problem.settings.seed = 11;
        problem.budget.rays = Some(200_000);
        let answer = solve(&problem, &mut |_: &crate::Progress| {
            ControlFlow::Continue(())
        })
        .unwrap();
        let rays = allocate(
            &answer.mesh,
            answer.estimate.radiosity(),
            probe_budget(200_000, answer.mesh.patches().len()),
        );
        let seen = probe(&answer.mesh, &answer.bvh, rays, 11);
        assert!(seen.escaped.iter().all(|&e| e == 0), "a closed furnace");
        let honest = closure(
            &answer.mesh,
            &answer.estimate,
            &seen,
            &Delivery::default(),
            &[],
        );
        assert_eq!(honest.warning(), None, "{honest:?}");
        // Pooled into one group, the patches' errors are one error: in the closed furnace (no
        // probe variance) the variance is `(sum c sqrt V)²`, between half and all of `n` times
        // `sum c² V` for patches this alike (Cauchy-Schwarz), and the balance is unchanged.
        let n = answer.mesh.patches().len();
        let one = closure(
            &answer.mesh,
            &answer.estimate,
            &seen,
            &Delivery::default(),
            &vec![0; n],
        );
        assert_eq!(one.balance, honest.balance);
        let (alone, pooled) = (honest.balance_se.unwrap(), one.balance_se.unwrap());
        for c in 0..3 {
            let ratio = (pooled[c] / alone[c]).powi(2) / n as f64;
            assert!((0.5..=1.0 + 1e-9).contains(&ratio), "{ratio}");
        }
        let e = &answer.estimate;
        let high = Estimate::new(
            e.radiosity().iter().map(|b| *b * 1.1).collect(),
            e.variance().map(<[_]>::to_vec),
            e.rays(),
        )
        .unwrap();
        let biased = closure(&answer.mesh, &high, &seen, &Delivery::default(), &[]);
        // B 10% high: absorbed = sum A (1 - rho) / rho (1.1 B - E) = 1.2 emitted
        let expected = -0.2 * biased.emitted[0];
        assert!((biased.balance[0] - expected).abs() < 0.02 * expected.abs());
        let warning = biased.warning().expect("flagged");
        assert!(warning.contains("red: emitted") && warning.contains("standard errors"));
    }

    /// A 4 x 4 m floor of reflectance 0.5 in patches of 5 cm (two blocks and more) under a sun
    /// at 30° elevation (700 W/m² facing it), nothing over it: every point receives
    /// `700 sin 30° = 350` W/m², so the delivery is `16 * 350` W with no variance, and its
    /// blocks' sums are the same on one thread and on four.
    #[test]
    fn the_light_delivery_is_exact_on_an_open_floor_on_any_thread_count() {
        use glam::Vec3;
        use mcrad_scene_io::{Face, Light, Material, Scene, Sun};
        let positions = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, 4.0),
            Vec3::new(4.0, 0.0, 4.0),
            Vec3::new(4.0, 0.0, 0.0),
        ];
        let floor = Face {
            vertices: vec![0, 1, 2, 3],
            material: 0,
            source: 0,
        };
        let grey = Material {
            name: "grey".into(),
            reflectance: Vec3::splat(0.5),
            emission: Vec3::ZERO,
        };
        let elevation = 30f64.to_radians();
        let sun = Light::Sun(Sun {
            direction: Vec3::new(elevation.cos() as f32, elevation.sin() as f32, 0.0),
            irradiance: DVec3::splat(700.0),
            diameter: 0.0,
        });
        let scene = Scene::new_lit(positions, vec![floor], vec![grey], vec![sun.clone()])
            .unwrap()
            .0;
        let mesh = Mesh::build(&scene, mcrad_meshing::Subdivision::MaxEdge(0.05)).unwrap();
        assert!(mesh.patches().len() > DELIVERY_BLOCK);
        let bvh = mesh.caster().unwrap();
        let rays = vec![3; mesh.patches().len()];
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| light_delivery(&mesh, &bvh, std::slice::from_ref(&sun), None, &rays, 7))
        };
        let one = on(1);
        assert_eq!(one, on(4));
        // the sun's direction is stored in f32: its sine to about 1e-7
        let exact = 16.0 * 700.0 * elevation.sin();
        for k in 0..3 {
            assert!((one.power[k] - exact).abs() < 1e-5 * exact, "{one:?}");
            assert!(one.variance[k].abs() < 1e-6 * exact * exact, "{one:?}");
        }
    }

    #[test]
    fn the_probe_takes_two_rays_per_patch_and_shares_the_rest_by_power() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../scenes/furnace.obj");
        let scene = mcrad_scene_io::load(&path).unwrap().scene;
        let mesh = Mesh::build(&scene, mcrad_meshing::Subdivision::None).unwrap();
        let n = mesh.patches().len();
        let mut b = vec![DVec3::ZERO; n];
        b[0] = DVec3::ONE;
        let rays = allocate(&mesh, &b, 2 * n as u64 + 100);
        assert_eq!(rays[0], 102);
        assert!(rays[1..].iter().all(|&k| k == 2));
        assert_eq!(probe_budget(1_600, 1_000), 2_000);
        assert_eq!(probe_budget(1_600_000, 1_000), 100_000);
    }
}
