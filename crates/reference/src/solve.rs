//! Gauss-Seidel on `B = E + ρ F B`.

use super::ReferenceError;
use super::matrix::FormFactors;
use glam::DVec3;
use mcrad_meshing::Mesh;

/// A solution of the radiosity system.
#[derive(Debug, Clone, PartialEq)]
pub struct Solution {
    /// Radiosity `B_i` per patch and RGB channel (W/m², exitance).
    pub radiosity: Vec<DVec3>,
    /// Gauss-Seidel sweeps done.
    pub iterations: usize,
    /// The final residual `max_{i,c} |E_ic + ρ_ic Σ_j F_ij B_jc - B_ic| / max_{i,c} B_ic`
    /// (dimensionless; 0 when nothing emits).
    pub residual: f64,
}

/// Solves `B_i = E_i + ρ_i Σ_j F_ij B_j` for each RGB channel by Gauss-Seidel sweeps in patch
/// order, starting from `B = E`, until the residual relative to the largest radiosity is at
/// most `residual` (checked after every sweep whose largest update is below it), or fails
/// after `max_iterations` sweeps. Each sweep shrinks the error by about the largest `ρ S_i`,
/// so a reflectance close to 1 in a closed scene needs many sweeps.
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
    let relative = |b: &[DVec3]| {
        let scale = b.iter().map(|x| x.max_element()).fold(0.0, f64::max);
        let worst = (0..b.len())
            .map(|i| {
                (emission[i] + rho[i] * factors.row_dot(i, b) - b[i])
                    .abs()
                    .max_element()
            })
            .fold(0.0, f64::max);
        if worst == 0.0 { 0.0 } else { worst / scale }
    };
    for sweep in 1..=max_iterations {
        let mut largest: f64 = 0.0;
        for i in 0..b.len() {
            let new = emission[i] + rho[i] * factors.row_dot(i, &b);
            largest = largest.max((new - b[i]).abs().max_element());
            b[i] = new;
        }
        let scale = b.iter().map(|x| x.max_element()).fold(0.0, f64::max);
        if largest <= residual * scale {
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
