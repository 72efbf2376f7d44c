//! The ambient term of progressive radiosity (Cohen, Chen, Wallace and Greenberg 1988; Balog,
//! section 3.1): a cheap stand-in for the light that power not yet shot would still add.
//!
//! A shooting run that stops early leaves unshot power `U_j` (W per channel) on the patches: it
//! is already in their own radiosity, but it has not lit anything else yet. Suppose it were
//! shot, that a share `e` of every watt shot left the scene (an open side; `e = 0` in a closed
//! scene), that the rest landed on the surfaces in proportion to their area (the form factor
//! `F_ij ≈ (1 - e) A_j / sum_k A_k`), and that each bounce reflected the area-weighted mean
//! reflectance `rho_avg = sum_j A_j rho_j / sum_j A_j`. Then every unit of area receives
//! `(1 - e) sum_j U_j / sum_j A_j` directly, `rho_avg (1 - e)` of that after one more bounce,
//! and so on: in all the **ambient irradiance** (W/m² arriving, per channel)
//!
//! ```text
//! A_amb = (1 - e) R sum_j U_j / sum_j A_j,      R = 1 / (1 - rho_avg (1 - e)),
//! ```
//!
//! of which patch `i` reflects `rho_i A_amb`: its displayed radiosity becomes
//! `B_i + rho_i A_amb` ([`with_ambient`]). In that model the power added,
//! `sum_i A_i rho_i A_amb`, is exactly the reflected power the unshot power would yet produce,
//! so a solution plus its ambient term conserves power. With `e = 0` this is Cohen, Chen,
//! Wallace and Greenberg's term; the shooter measures `e` as it goes
//! ([`ShootStats::escape_fraction`](crate::ShootStats::escape_fraction)): in the Cornell box,
//! open on one side, about 30% of the power shot escapes, and the closed-scene term overshoots
//! the reflected light by about a quarter of the unshot fraction.
//!
//! **Where it is biased.** The model is exact only where it holds: a scene of uniform
//! reflectance in which every patch sees the others in proportion to their area and escape is
//! the same from everywhere (a sphere's inside; for the mean over patches, any closed scene of
//! uniform reflectance). Elsewhere the term ignores visibility and distance (it lights shadowed
//! corners and closed-off rooms as much as the patches next to the unshot power, which it
//! under-lights), uses the escape share of the power shot so far for the power still to come,
//! and weights reflectance by area rather than by where the light lands. The bias is
//! proportional to the unshot power, so it vanishes as the shooting converges; the term adds no
//! variance estimate of its own.

use crate::error::Error;
use glam::DVec3;
use mcrad_combine::Estimate;
use mcrad_meshing::Mesh;

/// The area-weighted mean reflectance `rho_avg = sum_j A_j rho_j / sum_j A_j` per channel.
pub fn mean_reflectance(mesh: &Mesh) -> DVec3 {
    let (weighted, area) = mesh.patches().iter().fold((DVec3::ZERO, 0.0), |(w, a), p| {
        (w + p.reflectance.as_dvec3() * p.area, a + p.area)
    });
    weighted / area
}

/// The ambient irradiance `A_amb = (1 - e) R sum_j U_j / sum_j A_j` (W/m² per channel),
/// `R = 1 / (1 - rho_avg (1 - e))` with `rho_avg` the area-weighted mean reflectance per channel
/// ([`mean_reflectance`]), from the unshot power `unshot[j] = U_j` (W per channel, as in
/// [`Shooting::unshot`](crate::Shooting::unshot)) and the share `escape = e` of shot power that
/// leaves the scene (per channel in `[0, 1]`; `0` for a closed scene, or
/// [`ShootStats::escape_fraction`](crate::ShootStats::escape_fraction)). See the
/// [module documentation](self) for what it means and where it is biased.
///
/// Errors: `unshot` not one finite, non-negative value per patch; `escape` outside `[0, 1]`.
pub fn ambient(mesh: &Mesh, unshot: &[DVec3], escape: DVec3) -> Result<DVec3, Error> {
    let patches = mesh.patches().len();
    if unshot.len() != patches {
        return Err(Error::InputLength {
            patches,
            got: unshot.len(),
        });
    }
    if let Some(patch) = unshot
        .iter()
        .position(|u| !(u.is_finite() && u.min_element() >= 0.0))
    {
        return Err(Error::BadUnshot {
            patch,
            value: unshot[patch],
        });
    }
    if !(escape.min_element() >= 0.0 && escape.max_element() <= 1.0) {
        return Err(Error::BadEscape(escape));
    }
    let total: DVec3 = unshot.iter().sum();
    let kept = DVec3::ONE - escape;
    // Each reflectance channel is < 1, so R is finite.
    let r = (DVec3::ONE - mean_reflectance(mesh) * kept).recip();
    Ok(kept * r * total / mesh.total_area())
}

/// `estimate` with the ambient term added: `B_i + rho_i A_amb` per patch and channel (W/m²),
/// `ambient` = `A_amb` from [`ambient`]. Variances and the ray count are kept as they are (the
/// term is a deterministic function of the run; its bias is discussed in the
/// [module documentation](self)).
///
/// Errors: `estimate` not one value per patch, or a non-finite result.
pub fn with_ambient(mesh: &Mesh, estimate: &Estimate, ambient: DVec3) -> Result<Estimate, Error> {
    let patches = mesh.patches();
    if estimate.len() != patches.len() {
        return Err(Error::InputLength {
            patches: patches.len(),
            got: estimate.len(),
        });
    }
    let radiosity = estimate
        .radiosity()
        .iter()
        .zip(patches)
        .map(|(b, p)| *b + p.reflectance.as_dvec3() * ambient)
        .collect();
    Ok(Estimate::new(
        radiosity,
        estimate.variance().map(<[DVec3]>::to_vec),
        estimate.rays(),
    )?)
}
