//! Gauss-Seidel on `B = E + ρ F B`.

use super::ReferenceError;
use super::matrix::FormFactors;
use glam::DVec3;
use mcrad_meshing::Mesh;

/// Patches dimmer than this share of the largest radiosity are held to an absolute residual,
/// `residual × DIM_FLOOR × max B` (W/m²), instead of one relative to their own radiosity: a
/// patch in full shadow (radiosity 0 or nearly) does not hold up the solve.
pub const DIM_FLOOR: f64 = 1e-6;

/// A solution of the radiosity system.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    /// Radiosity `B_i` per patch and RGB channel (W/m², exitance).
    pub radiosity: Vec<DVec3>,
    /// Gauss-Seidel sweeps done.
    pub iterations: usize,
    /// The final residual relative to each patch's own radiosity,
    /// `max_{i,c} |E_ic + ρ_ic Σ_j F_ij B_jc - B_ic| / max(B_ic, DIM_FLOOR max_{k,c'} B_kc')`
    /// (dimensionless; 0 when nothing emits). The error of `B_ic` left is about this times
    /// `B_ic / (1 - ρ)` for the scene's reflectance `ρ`.
    pub residual: f64,
}

/// Solves `B_i = E_i + ρ_i Σ_j F_ij B_j` for each RGB channel by Gauss-Seidel sweeps in patch
/// order, starting from `B = E`, until every patch's residual relative to its own radiosity
/// is at most `residual` (see [`Solution::residual`]; checked after every sweep whose updates
/// are all below it), or fails after `max_iterations` sweeps. Each sweep shrinks the error by
/// about the largest `ρ S_i`, so a reflectance close to 1 in a closed scene needs many sweeps.
///
/// The residual is relative per patch, not to the largest radiosity: a small bright light
/// (1 W from 1 cm², `E = 1e4` W/m²) would otherwise set the scale, and the dim walls it lights
/// (`B` about 1e-2 W/m²) would be left short by up to `1e-9 × 1e4 / 1e-2`, 1e-3 of their
/// radiosity. Gauss-Seidel from `B = E` approaches the solution from below, so what is left
/// short is a bias of the reference, not noise.
pub fn solve(
    mesh: &Mesh,
    factors: &FormFactors,
    residual: f64,
    max_iterations: usize,
) -> Result<Solution, ReferenceError> {
    if !(residual > 0.0 && residual.is_finite()) {
        return Err(ReferenceError::BadResidual(residual));
    }
    let patches = mesh.patches();
    if patches.len() != factors.len() {
        return Err(ReferenceError::MatrixSize {
            patches: patches.len(),
            rows: factors.len(),
        });
    }
    let emission: Vec<DVec3> = patches.iter().map(|p| p.emission.as_dvec3()).collect();
    let rho: Vec<DVec3> = patches.iter().map(|p| p.reflectance.as_dvec3()).collect();
    let mut b = emission.clone();
    let floor = |b: &[DVec3]| DIM_FLOOR * b.iter().map(|x| x.max_element()).fold(0.0, f64::max);
    // The largest of |d_ic| / max(B_ic, floor) over the patches and channels.
    let relative_to = |d: DVec3, b: DVec3, floor: f64| {
        let d = d.abs();
        let s = b.max(DVec3::splat(floor));
        (0..3)
            .map(|c| if d[c] == 0.0 { 0.0 } else { d[c] / s[c] })
            .fold(0.0, f64::max)
    };
    let relative = |b: &[DVec3]| {
        let floor = floor(b);
        (0..b.len())
            .map(|i| {
                relative_to(
                    emission[i] + rho[i] * factors.row_dot(i, b) - b[i],
                    b[i],
                    floor,
                )
            })
            .fold(0.0, f64::max)
    };
    for sweep in 1..=max_iterations {
        let mut largest: f64 = 0.0;
        let below = floor(&b);
        for i in 0..b.len() {
            let new = emission[i] + rho[i] * factors.row_dot(i, &b);
            largest = largest.max(relative_to(new - b[i], new, below));
            b[i] = new;
        }
        if largest <= residual {
            let r = relative(&b);
            if r <= residual {
                return Ok(Solution {
                    radiosity: b,
                    iterations: sweep,
                    residual: r,
                });
            }
        }
    }
    let r = relative(&b);
    if r <= residual {
        // Only reachable with max_iterations == 0 and B = E already a solution.
        return Ok(Solution {
            radiosity: b,
            iterations: max_iterations,
            residual: r,
        });
    }
    Err(ReferenceError::NotConverged {
        iterations: max_iterations,
        residual: r,
        target: residual,
    })
}
