//! Pooling an answer over clusters of small faces ([`mcrad_meshing::Clusters`]).
//!
//! Each member `f` of a cluster keeps its own reflectance `rho_f` and emission `E_f`; the
//! cluster shares one incident irradiance per channel, the members' estimates
//! `H_f = (B_f - E_f) / rho_f` merged with weights `rho_f A_f`:
//! `H = sum A_f (B_f - E_f) / sum rho_f A_f`, so the reflected power `sum A_f (B_f - E_f)` is
//! the same before and after (exact power conservation). Each member's radiosity becomes
//! `E_f + rho_f H` with variance `rho_f² Var H`, `Var H = sum A_f² Var B_f / (sum rho_f A_f)²`
//! (the members' estimates taken as independent). Two members' `(B - E) / rho` are then equal:
//! their ratio of reflected radiosity is exactly that of their reflectances.
//!
//! Before pooling, the cluster's light is tested: per channel, the members' `H_f` against the
//! pooled `H` by a chi-square of `(H_f - H)² / Var H_f` over the members (a member's variance
//! floored at a quarter of the cluster's mean: a face of few rays can report 0). A cluster is
//! split when in some channel the statistic exceeds its degrees of freedom `d` by more than
//! [`SPLIT_SIGMAS`] `sqrt(2 d)` and the area-weighted root mean square of `H_f - H` exceeds
//! [`SPLIT_RELATIVE`] of `H` (a shadow or a gradient across it, beyond its noise and large
//! enough to matter): its members are cut in two at the median of their centroids along the
//! centroids' longest extent, and each half is tested again, down to single faces, which keep
//! their own estimates, or to groups smaller than the test's smallest span ([`Clusters::span`]:
//! twice the refinement's smallest edge, so that a group is cut no finer than a large face
//! would be, whatever its faces' tessellation).

use glam::DVec3;
use mcrad_combine::{Estimate, EstimateError};
use mcrad_meshing::{Clusters, Mesh};
use std::borrow::Cow;

/// A cluster is split when its chi-square exceeds its degrees of freedom by this many of its
/// standard deviations (`sqrt(2 d)`) in some channel (see the module documentation).
pub(crate) const SPLIT_SIGMAS: f64 = 3.0;

/// ... and the members' spread of incident irradiance (area-weighted root mean square) exceeds
/// this fraction of the pooled irradiance: the marks' 2% of a refinement.
pub(crate) const SPLIT_RELATIVE: f64 = 0.02;

/// What pooling did: the estimates shared after the tests.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub(crate) struct PoolCounts {
    /// Groups of at least two faces that share one estimate.
    pub groups: usize,
    /// Faces in those groups.
    pub faces: usize,
    /// Splits of a group in two by the test.
    pub splits: usize,
}

/// Per patch, the group whose estimate it shares after pooling ([`pool_clusters`]; numbered
/// from 0), or [`ALONE`]: the members of a group have fully correlated errors (one `H` each).
pub(crate) type Groups = Vec<u32>;

/// A patch that shares no estimate.
pub(crate) const ALONE: u32 = u32::MAX;

/// `estimate` pooled over `clusters` of `mesh` (see the module documentation), what the
/// pooling did, and the groups that share an estimate; `test`: the smallest span (scene units)
/// of a cluster that is tested and split first where the light varies across it, or `None`
/// to pool every cluster whole. An estimate without variances is returned as it is (nothing
/// to test against). An estimate handed over is pooled in place (not copied: 48 bytes a patch).
pub(crate) fn pool_clusters(
    mesh: &Mesh,
    clusters: &Clusters,
    estimate: Cow<'_, Estimate>,
    test: Option<f64>,
) -> Result<(Estimate, PoolCounts, Groups), EstimateError> {
    let mut counts = PoolCounts::default();
    let mut groups = vec![ALONE; mesh.patches().len()];
    if estimate.variance().is_none() {
        return Ok((estimate.into_owned(), counts, groups));
    }
    let rays = estimate.rays();
    let (mut b, v, _) = estimate.into_owned().into_parts();
    let mut v = v.unwrap_or_default();
    let mut members: Vec<u32> = Vec::new();
    for cluster in clusters.iter() {
        members.clear();
        members.extend_from_slice(cluster);
        settle(
            mesh,
            &mut members,
            &mut b,
            &mut v,
            &mut groups,
            &mut counts,
            test,
        );
    }
    Ok((Estimate::new(b, Some(v), rays)?, counts, groups))
}

/// Tests `members` and pools them into `b`, `v` (numbering their group in `groups`), or
/// splits them and goes on with each half.
fn settle(
    mesh: &Mesh,
    members: &mut [u32],
    b: &mut [DVec3],
    v: &mut [DVec3],
    groups: &mut [u32],
    counts: &mut PoolCounts,
    test: Option<f64>,
) {
    if members.len() < 2 {
        return;
    }
    let patches = mesh.patches();
    // per channel: sum rho A, sum A (B - E), sum A² Var B
    let (mut weight, mut power, mut spread) = (DVec3::ZERO, DVec3::ZERO, DVec3::ZERO);
    for &i in members.iter() {
        let (p, i) = (&patches[i as usize], i as usize);
        weight += p.reflectance.as_dvec3() * p.area;
        power += (b[i] - p.emission.as_dvec3()) * p.area;
        spread += v[i] * p.area * p.area;
    }
    let pooled = DVec3::select(weight.cmpgt(DVec3::ZERO), power / weight, DVec3::ZERO);
    let tested = test.is_some_and(|min| Clusters::span(mesh, members) >= min);
    if tested && varies(mesh, members, b, v, pooled) {
        // cut at the median along the centroids' longest extent
        Clusters::sort_along_extent(mesh, members);
        counts.splits += 1;
        let (left, right) = members.split_at_mut(members.len() / 2);
        settle(mesh, left, b, v, groups, counts, test);
        settle(mesh, right, b, v, groups, counts, test);
        return;
    }
    let var_h = DVec3::select(
        weight.cmpgt(DVec3::ZERO),
        spread / (weight * weight),
        DVec3::ZERO,
    );
    for &i in members.iter() {
        let (p, i) = (&patches[i as usize], i as usize);
        groups[i] = counts.groups as u32;
        let rho = p.reflectance.as_dvec3();
        for c in 0..3 {
            // a channel no member reflects keeps its members' own values
            if weight[c] > 0.0 {
                b[i][c] = f64::from(p.emission[c]) + rho[c] * pooled[c];
                v[i][c] = rho[c] * rho[c] * var_h[c];
            }
        }
    }
    counts.groups += 1;
    counts.faces += members.len();
}

/// Whether the members' incident irradiance varies across them beyond their noise and beyond
/// [`SPLIT_RELATIVE`] of `pooled` in some channel (see the module documentation).
fn varies(mesh: &Mesh, members: &[u32], b: &[DVec3], v: &[DVec3], pooled: DVec3) -> bool {
    let patches = mesh.patches();
    (0..3).any(|c| {
        // the members that reflect this channel: H_f and Var H_f
        let own = || {
            members.iter().filter_map(move |&i| {
                let p = &patches[i as usize];
                let rho = f64::from(p.reflectance[c]);
                let i = i as usize;
                (rho > 0.0).then(|| {
                    let h = (b[i][c] - f64::from(p.emission[c])) / rho;
                    (h, v[i][c] / (rho * rho), p.area)
                })
            })
        };
        let (n, var_sum) = own().fold((0usize, 0.0), |(n, s), (_, var, _)| (n + 1, s + var));
        if n < 2 || pooled[c] <= 0.0 {
            return false;
        }
        let floor = var_sum / n as f64 / 4.0;
        let (mut chi2, mut sq, mut area) = (0.0, 0.0, 0.0);
        for (h, var, a) in own() {
            let d = h - pooled[c];
            if floor > 0.0 {
                chi2 += d * d / var.max(floor);
            }
            sq += a * d * d;
            area += a;
        }
        let dof = (n - 1) as f64;
        // without any variance the spread alone decides
        let noisy = floor > 0.0 && chi2 <= dof + SPLIT_SIGMAS * (2.0 * dof).sqrt();
        let material = (sq / area).sqrt() > SPLIT_RELATIVE * pooled[c];
        material && !noisy
    })
}
