//! The form-factor matrix, in two passes over the unordered pairs `i < j` (method: the
//! [module documentation](super)).

use super::form_factor::{clip_above, contour};
use super::quadrature::{Adaptive, integrate_adaptive};
use super::shaft::{FaceInput, Occluders};
use super::visibility::{Grid, Side, fan};
use super::{ReferenceConfig, ReferenceError};
use glam::{DVec3, Vec3};
use mcrad_meshing::Mesh;
use mcrad_raycast::RayCaster;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::sync::atomic::{self, AtomicUsize};

/// The least number of visibility blocks of a pair's first sweep (two rays each).
const MIN_BLOCKS: usize = 16;
/// The most visibility blocks per pair (two rays each per sweep).
const MAX_BLOCKS: usize = 1 << 18;
/// The most visibility sweeps per pair.
const MAX_SWEEPS: usize = 32;
/// Deepest quadrature subdivision: a triangle `4^-24` (about `3.6e-15`) of its fan triangle.
const MAX_QUAD_DEPTH: u8 = 24;
/// Quadrature refinements allowed per pair.
const MAX_QUAD_REFINEMENTS: usize = 4096;

/// A sparse form-factor matrix: for each patch `i` (mesh order) the patches `j` with
/// `F_ij > 0`, ascending, and the form factors (dimensionless, `Σ_j F_ij <= 1`, equal to 1 in a
/// closed scene). Zeros are not stored. Reciprocity `A_i F_ij = A_j F_ji` holds to rounding.
#[derive(Debug, Clone, PartialEq)]
pub struct FormFactors {
    rows: Vec<Row>,
    stats: FormFactorStats,
}

#[derive(Debug, Clone, PartialEq, Default)]
struct Row {
    cols: Vec<u32>,
    vals: Vec<f64>,
}

/// Work and accuracy of a form-factor computation. Errors are relative to the row sum `S_r`
/// (at least `0.1 ×` the area-weighted mean row sum).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FormFactorStats {
    /// Shadow rays cast.
    pub rays: u64,
    /// Point-to-polygon form factors evaluated (quadrature nodes, visibility weights, bounds).
    pub evaluations: u64,
    /// Non-zero entries kept.
    pub nonzeros: usize,
    /// Unordered pairs `{i, j}` with an occluder in their shaft: their visibility was
    /// estimated (by shadow rays or an analytic bound) rather than known to be 1.
    pub occluded_pairs: u64,
    /// The largest estimated quadrature error of a row (conservative: a sum of the embedded
    /// rules' differences), relative to its sum.
    pub max_quadrature_error: f64,
    /// The largest estimated visibility error of a row (one standard deviation), relative to
    /// its sum.
    pub max_visibility_error: f64,
    /// Rows whose estimated errors stayed above the tolerances because a work limit was reached.
    pub rows_over_tolerance: usize,
}

impl FormFactors {
    /// Number of rows (patches).
    pub fn len(&self) -> usize {
        self.rows.len()
    }

    /// True when there are no rows.
    pub fn is_empty(&self) -> bool {
        self.rows.is_empty()
    }

    /// Row `i`: the patch indices `j` with `F_ij > 0` (ascending) and the form factors.
    ///
    /// # Panics
    /// If `i >= len()`.
    pub fn row(&self, i: usize) -> (&[u32], &[f64]) {
        let r = &self.rows[i];
        (&r.cols, &r.vals)
    }

    /// `F_ij` (dimensionless), 0 when not stored.
    ///
    /// # Panics
    /// If `i >= len()`.
    pub fn get(&self, i: usize, j: usize) -> f64 {
        let r = &self.rows[i];
        u32::try_from(j)
            .ok()
            .and_then(|j| r.cols.binary_search(&j).ok())
            .map_or(0.0, |k| r.vals[k])
    }

    /// The row sum `S_i = Σ_j F_ij`: the fraction of the power leaving patch `i` that lands on
    /// a front face (1 in a closed scene).
    ///
    /// # Panics
    /// If `i >= len()`.
    pub fn row_sum(&self, i: usize) -> f64 {
        self.rows[i].vals.iter().sum()
    }

    /// Work and accuracy counters.
    pub fn stats(&self) -> &FormFactorStats {
        &self.stats
    }

    /// `Σ_j F_ij x_j` for row `i` (per RGB channel).
    #[inline]
    pub(crate) fn row_dot(&self, i: usize, x: &[DVec3]) -> DVec3 {
        let r = &self.rows[i];
        r.cols
            .iter()
            .zip(&r.vals)
            .fold(DVec3::ZERO, |acc, (&j, &f)| acc + x[j as usize] * f)
    }
}

/// The form-factor matrix of `mesh`, with visibility from `caster` (its ids must be the patch
/// indices, as for a [`mcrad_raycast::Bvh`] built from [`Mesh::triangle_patch`]).
///
/// Each row `r` is refined until its quadrature error is below
/// [`ReferenceConfig::tolerance`] `× S_r` and the standard deviation of its visibility error
/// below [`ReferenceConfig::visibility_tolerance`] `× S_r`, `S_r = Σ_j F_rj` (but at least
/// `0.1 ×` the area-weighted mean row sum), or until a work limit per pair is reached (counted
/// in [`FormFactorStats::rows_over_tolerance`]). The [module documentation](super) has the
/// method. The work runs in two passes over the rows on the current rayon pool, and `progress`
/// is called from the worker threads after each row of each pass with the number of rows done,
/// each pass counting half (so the values run up to the patch count, not necessarily in
/// order). The result does not depend on the thread count.
///
/// Refuses a mesh with more than [`ReferenceConfig::max_patches`] patches before any work.
pub fn form_factors<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    config: &ReferenceConfig,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<FormFactors, ReferenceError> {
    let n = mesh.patches().len();
    if n > config.max_patches || n >= u32::MAX as usize {
        return Err(ReferenceError::TooManyPatches {
            patches: n,
            limit: config.max_patches.min(u32::MAX as usize - 1),
        });
    }
    for (name, value) in [
        ("tolerance", config.tolerance),
        ("visibility_tolerance", config.visibility_tolerance),
    ] {
        if !(value > 0.0 && value < 1.0) {
            return Err(ReferenceError::BadTolerance { name, value });
        }
    }
    let geometry = Geometry::new(mesh);
    let done = AtomicUsize::new(0);
    // Each pass counts half a row: the last call says `n`.
    let tick = || {
        let halves = done.fetch_add(1, atomic::Ordering::Relaxed) + 1;
        progress(halves / 2);
    };

    // Pass 1: every pair clipped, culled and integrated; occluded pairs get one sweep of rays.
    let first: Vec<(Vec<PairRecord>, Work)> = (0..n)
        .into_par_iter()
        .map(|i| {
            let row = first_pass(i, &geometry, caster, config.tolerance);
            tick();
            row
        })
        .collect();
    let (mut records, mut work): (Vec<Vec<PairRecord>>, Vec<Work>) = first.into_iter().unzip();

    // The visibility budgets need the row sums, from the first sweeps' visible fractions.
    let mut sum = vec![0.0; n];
    let mut occluded_sum = vec![0.0; n];
    for (i, row) in records.iter().enumerate() {
        for r in row {
            let g = r.exchange_seen() + f64::from(r.vis_error);
            let j = r.j as usize;
            sum[i] += g / geometry.area[i];
            sum[j] += g / geometry.area[j];
            if r.occluded {
                occluded_sum[i] += g / geometry.area[i];
                occluded_sum[j] += g / geometry.area[j];
            }
        }
    }
    // A row that receives almost nothing (a patch under a block) is held to the budget of one
    // that receives a tenth of the average, not to a fraction of its own tiny sum.
    let floor = ROW_SUM_FLOOR * mean_row_sum(&sum, &geometry.area);
    for s in &mut sum {
        *s = s.max(floor);
    }
    let budget = Budget {
        tolerance: config.visibility_tolerance,
        sum: &sum,
        occluded_sum: &occluded_sum,
    };

    // Pass 2: occluded pairs refined to their budgets.
    records
        .par_iter_mut()
        .zip(work.par_iter_mut())
        .enumerate()
        .for_each(|(i, (row, w))| {
            second_pass(i, row, w, &geometry, caster, &budget);
            tick();
        });

    Ok(assemble(records, &work, &geometry, config))
}

/// Rows are held to a tolerance relative to their sum, but not below this fraction of the
/// area-weighted mean row sum.
const ROW_SUM_FLOOR: f64 = 0.1;

/// The area-weighted mean of the row sums.
fn mean_row_sum(sums: &[f64], areas: &[f64]) -> f64 {
    let total: f64 = areas.iter().sum();
    if total > 0.0 {
        sums.iter().zip(areas).map(|(s, a)| s * a).sum::<f64>() / total
    } else {
        0.0
    }
}

/// Rays and evaluations of one row.
#[derive(Debug, Default, Clone, Copy)]
struct Work {
    rays: u64,
    evaluations: u64,
    occluded: u64,
}

/// What pass 1 and 2 find about the pair `(i, j)`, `i < j`, kept in row `i` (32 bytes: there
/// are up to `n² / 2` of them). Errors and bounds need no more than f32.
#[derive(Debug, Clone, Copy)]
struct PairRecord {
    /// Unoccluded exchange `U_ij = A_i F_ij^unoccluded` (scene units²).
    exchange: f64,
    j: u32,
    /// Visible fraction `φ_ij` (exactly 1 for unoccluded pairs).
    phi: f32,
    /// The quadrature error estimate of `U_ij` (scene units²).
    quad_error: f32,
    /// The error estimate of `φ_ij U_ij` (scene units², one standard deviation).
    vis_error: f32,
    /// An upper bound of the blocked exchange `(1 - φ) U_ij` from the occluders' outlines
    /// (scene units²), computed when every ray of the first sweep passed; infinite otherwise.
    bound: f32,
    /// An occluder meets the pair's shaft: `phi` is an estimate.
    occluded: bool,
}

impl PairRecord {
    /// `G_ij = φ_ij U_ij` (scene units²).
    fn exchange_seen(&self) -> f64 {
        f64::from(self.phi) * self.exchange
    }
}

/// Visibility error budgets (pass 2).
struct Budget<'a> {
    tolerance: f64,
    sum: &'a [f64],
    occluded_sum: &'a [f64],
}

impl Budget<'_> {
    /// The allowed error of `φ_ij U_ij` (scene units²): the smaller of the two rows' shares,
    /// for the exchange `(φ + δφ) U` (the probe's `φ` can be 0 in a partly visible pair).
    fn target(&self, geometry: &Geometry, i: usize, r: &PairRecord) -> f64 {
        let g = r.exchange_seen() + f64::from(r.vis_error);
        [i, r.j as usize]
            .into_iter()
            .filter(|&k| self.occluded_sum[k] > 0.0)
            .map(|k| {
                let a = geometry.area[k];
                self.tolerance * self.sum[k] * (a * g / self.occluded_sum[k]).sqrt()
            })
            .fold(f64::INFINITY, f64::min)
    }
}

/// Patch polygons and planes in f64.
struct Geometry {
    corners: Vec<DVec3>,
    first: Vec<usize>,
    normal: Vec<DVec3>,
    normal32: Vec<Vec3>,
    offset: Vec<f64>,
    area: Vec<f64>,
    /// Per patch: its plane group, the patches of one input face that share a plane (a
    /// non-planar face is split into triangles that keep its number).
    group: Vec<u32>,
    /// Signed distances to a plane within this are "on the plane" (scene units): rounding of
    /// f32 vertices and of planes fitted to them.
    eps: f64,
    /// The plane groups as occluders.
    occluders: Occluders,
}

impl Geometry {
    fn new(mesh: &Mesh) -> Geometry {
        let pos = mesh.positions();
        let mut g = Geometry {
            corners: Vec::new(),
            first: vec![0],
            normal: Vec::new(),
            normal32: Vec::new(),
            offset: Vec::new(),
            area: Vec::new(),
            group: Vec::new(),
            eps: 0.0,
            occluders: Occluders::new(Vec::new(), 0.0),
        };
        let (mut lo, mut hi) = (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY));
        for p in mesh.patches() {
            let start = g.corners.len();
            g.corners
                .extend(mesh.corners(p).iter().map(|&v| pos[v as usize].as_dvec3()));
            let poly = &g.corners[start..];
            // Newell's normal: twice the vector area, from the f64 corners.
            let mut twice = DVec3::ZERO;
            for (k, a) in poly.iter().enumerate() {
                twice += a.cross(poly[(k + 1) % poly.len()]);
            }
            let n = twice.try_normalize().unwrap_or(p.normal.as_dvec3());
            let centroid = poly.iter().sum::<DVec3>() / poly.len() as f64;
            for v in poly {
                lo = lo.min(*v);
                hi = hi.max(*v);
            }
            g.first.push(g.corners.len());
            g.normal.push(n);
            g.normal32.push(p.normal);
            g.offset.push(n.dot(centroid));
            g.area.push(p.area);
        }
        if lo.x.is_finite() {
            let magnitude = lo.abs().max(hi.abs()).max_element();
            g.eps = 1e-6 * (hi - lo).length() + 1e-7 * magnitude;
        }
        // Plane groups: patches of one face whose planes agree (normals within about 1.4e-3 rad,
        // offsets within eps), in order of first appearance.
        let mut groups: Vec<FaceInput> = Vec::new();
        let mut by_face: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
        for (i, p) in mesh.patches().iter().enumerate() {
            let (n, d) = (g.normal[i], g.offset[i]);
            let candidates = by_face.entry(p.face).or_default();
            let found = candidates.iter().copied().find(|&k| {
                let f = &groups[k as usize];
                f.normal.dot(n) > 1.0 - 1e-6 && (f.offset - d).abs() <= g.eps
            });
            let k = found.unwrap_or_else(|| {
                groups.push(FaceInput {
                    face: groups.len() as u32,
                    normal: n,
                    offset: d,
                    points: Vec::new(),
                });
                candidates.push(groups.len() as u32 - 1);
                groups.len() as u32 - 1
            });
            groups[k as usize].points.extend_from_slice(g.polygon(i));
            g.group.push(k);
        }
        g.occluders = Occluders::new(groups, g.eps);
        g
    }

    fn polygon(&self, i: usize) -> &[DVec3] {
        &self.corners[self.first[i]..self.first[i + 1]]
    }

    /// Signed distance of `v` above the plane of patch `i`.
    #[inline]
    fn height(&self, i: usize, v: DVec3) -> f64 {
        self.normal[i].dot(v) - self.offset[i]
    }
}

impl Geometry {
    /// The unit normal of patch `i` as one side of a pair.
    fn side(&self, i: usize) -> Side {
        Side {
            id: i as u32,
            normal: self.normal[i],
            normal32: self.normal32[i],
        }
    }

    /// Clips `P_i` to the front of `P_j` (into `a`) and `P_j` to the front of `P_i` (into
    /// `b`); false when the two cannot exchange light (no front part, or one plane group).
    fn clip_pair(&self, i: usize, j: usize, a: &mut Vec<DVec3>, b: &mut Vec<DVec3>) -> bool {
        if self.group[i] == self.group[j] {
            return false;
        }
        let (pi, pj) = (self.polygon(i), self.polygon(j));
        if !pj.iter().any(|v| self.height(i, *v) > self.eps)
            || !pi.iter().any(|v| self.height(j, *v) > self.eps)
        {
            return false;
        }
        clip_above(pi, self.normal[j], self.offset[j], self.eps, a);
        clip_above(pj, self.normal[i], self.offset[i], self.eps, b);
        !a.is_empty() && !b.is_empty()
    }

    /// The unoccluded exchange `U_ij = ∫_{P_i'} F_{x→P_j'} dA_x = ∫_{P_j'} F_{y→P_i'} dA_y`
    /// (scene units²) over the smaller of the two clipped polygons.
    fn exchange(&self, i: usize, j: usize, a: &[DVec3], b: &[DVec3], tolerance: f64) -> Adaptive {
        let (outer, normal, target) = if polygon_area(a) <= polygon_area(b) {
            (a, self.normal[i], b)
        } else {
            (b, self.normal[j], a)
        };
        // An absolute floor that adds at most 1e-3 of the tolerance to any row sum.
        let floor = tolerance * 1e-3 * self.area[i].min(self.area[j]) / self.area.len() as f64;
        integrate_adaptive(
            outer,
            tolerance,
            floor,
            MAX_QUAD_DEPTH,
            MAX_QUAD_REFINEMENTS,
            |x| contour(x, normal, target),
        )
    }
}

impl Geometry {
    /// The visibility grid of the pair `(i, j)`, `i < j`, for clipped polygons `a` and `b`.
    fn grid(&self, i: usize, j: usize, a: &[DVec3], b: &[DVec3]) -> Grid {
        // Enough rounds for the first sweep's grid of at least MIN_BLOCKS blocks.
        let rounds = 3;
        let key = (i * self.area.len() + j) as u64;
        Grid::new(self.side(i), a, self.side(j), b, key, rounds)
    }
}

impl Geometry {
    /// An upper bound of the exchange between `P_i'` (`a`) and `P_j'` (`b`) that the clipped
    /// occluders can block (scene units²): every blocked segment crosses one of them, so the
    /// blocked part is at most `Σ_Q min(∫_{P_i'} F_{x→Q} dA_x, ∫_{P_j'} F_{y→Q} dA_y)`, each
    /// integral taken with a coarse adaptive rule plus its error estimate.
    fn blocked_bound(
        &self,
        i: usize,
        j: usize,
        a: &[DVec3],
        b: &[DVec3],
        occluders: &[Vec<DVec3>],
        work: &mut Work,
    ) -> f64 {
        let mut clipped = Vec::new();
        let mut side = |k: usize, poly: &[DVec3], q: &[DVec3]| {
            clip_above(q, self.normal[k], self.offset[k], self.eps, &mut clipped);
            if clipped.len() < 3 {
                return 0.0;
            }
            let n = self.normal[k];
            let r = integrate_adaptive(poly, 0.05, 0.0, 8, 64, |x| contour(x, n, &clipped));
            work.evaluations += r.evaluations;
            r.value + r.error
        };
        occluders
            .iter()
            .map(|q| {
                let from_i = side(i, a, q);
                from_i.min(side(j, b, q))
            })
            .sum()
    }
}

fn polygon_area(poly: &[DVec3]) -> f64 {
    fan(poly)
        .map(|t| 0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length())
        .sum()
}

/// Pass 1 for row `i`: the pairs `(i, j > i)` that exchange light, probed and integrated.
fn first_pass<C: RayCaster>(
    i: usize,
    geometry: &Geometry,
    caster: &C,
    tolerance: f64,
) -> (Vec<PairRecord>, Work) {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    let mut occluders = Vec::new();
    let mut records = Vec::new();
    let mut work = Work::default();
    for j in i + 1..geometry.area.len() {
        if !geometry.clip_pair(i, j, &mut a, &mut b) {
            continue;
        }
        occluders.clear();
        geometry.occluders.in_shaft(
            &a,
            &b,
            [geometry.group[i], geometry.group[j]],
            &mut occluders,
        );
        let q = geometry.exchange(i, j, &a, &b, tolerance);
        work.evaluations += q.evaluations;
        if q.value.is_nan() || q.value <= 0.0 {
            continue;
        }
        let occluded = !occluders.is_empty();
        let (mut phi, mut vis_error, mut bound) = (1.0, 0.0, f64::INFINITY);
        if occluded {
            work.occluded += 1;
            let grid = geometry.grid(i, j, &a, &b);
            let v = grid.refine(caster, grid.rounds_for(MIN_BLOCKS), 0.0, MAX_BLOCKS, 1);
            work.rays += v.rays;
            work.evaluations += v.evaluations;
            (phi, vis_error) = (v.fraction, v.error * q.value);
            if v.lit == 2 * v.blocks {
                // Every ray passed: the occluders may only graze the shaft, and the analytic
                // bound on what they can block may say more than the rays.
                bound = geometry
                    .blocked_bound(i, j, &a, &b, &occluders, &mut work)
                    .min(q.value);
                if 0.5 * bound < vis_error {
                    (phi, vis_error) = (1.0 - 0.5 * bound / q.value, 0.5 * bound);
                }
            }
        }
        records.push(PairRecord {
            exchange: q.value,
            j: j as u32,
            phi: phi as f32,
            quad_error: q.error as f32,
            vis_error: vis_error as f32,
            bound: bound as f32,
            occluded,
        });
    }
    (records, work)
}

/// Pass 2 for row `i`: its partly visible pairs refined until they meet their budgets.
fn second_pass<C: RayCaster>(
    i: usize,
    records: &mut [PairRecord],
    work: &mut Work,
    geometry: &Geometry,
    caster: &C,
    budget: &Budget,
) {
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for r in records.iter_mut().filter(|r| r.occluded) {
        let target = budget.target(geometry, i, r);
        if f64::from(r.vis_error) <= target {
            continue;
        }
        let j = r.j as usize;
        geometry.clip_pair(i, j, &mut a, &mut b);
        let grid = geometry.grid(i, j, &a, &b);
        let v = grid.refine(
            caster,
            grid.rounds_for(MIN_BLOCKS),
            target / r.exchange,
            MAX_BLOCKS,
            MAX_SWEEPS,
        );
        work.rays += v.rays;
        work.evaluations += v.evaluations;
        let bound = f64::from(r.bound);
        let (phi, error) = if v.error * r.exchange < 0.5 * bound {
            (v.fraction, v.error * r.exchange)
        } else {
            (1.0 - 0.5 * bound / r.exchange, 0.5 * bound)
        };
        r.phi = phi as f32;
        r.vis_error = error as f32;
    }
}

/// The rows, from the pairs in both directions, and the statistics.
fn assemble(
    records: Vec<Vec<PairRecord>>,
    work: &[Work],
    geometry: &Geometry,
    config: &ReferenceConfig,
) -> FormFactors {
    let n = records.len();
    let mut counts = vec![0usize; n];
    for (i, row) in records.iter().enumerate() {
        for r in row.iter().filter(|r| r.exchange_seen() > 0.0) {
            counts[i] += 1;
            counts[r.j as usize] += 1;
        }
    }
    let mut rows: Vec<Row> = counts
        .iter()
        .map(|&c| Row {
            cols: Vec::with_capacity(c),
            vals: Vec::with_capacity(c),
        })
        .collect();
    let mut quad = vec![0.0; n];
    let mut vis = vec![0.0; n];
    // Row r gets (k, r) for k < r while k runs, then (r, j > r): ascending columns. Each row of
    // records is dropped once read.
    for (i, row) in records.into_iter().enumerate() {
        for r in row {
            let j = r.j as usize;
            let g = r.exchange_seen();
            for (from, to) in [(i, j), (j, i)] {
                let a = geometry.area[from];
                if g > 0.0 {
                    rows[from].cols.push(to as u32);
                    rows[from].vals.push(g / a);
                }
                quad[from] += f64::from(r.phi) * f64::from(r.quad_error) / a;
                vis[from] += (f64::from(r.vis_error) / a).powi(2);
            }
        }
    }
    let sums: Vec<f64> = rows.iter().map(|r| r.vals.iter().sum()).collect();
    let floor = ROW_SUM_FLOOR * mean_row_sum(&sums, &geometry.area);
    let mut stats = FormFactorStats::default();
    for w in work {
        stats.rays += w.rays;
        stats.evaluations += w.evaluations;
        stats.occluded_pairs += w.occluded;
    }
    for (r, row) in rows.iter().enumerate() {
        stats.nonzeros += row.cols.len();
        let sum = sums[r].max(floor);
        if sum > 0.0 {
            let (q, v) = (quad[r] / sum, vis[r].sqrt() / sum);
            stats.max_quadrature_error = stats.max_quadrature_error.max(q);
            stats.max_visibility_error = stats.max_visibility_error.max(v);
            stats.rows_over_tolerance +=
                usize::from(q > config.tolerance || v > config.visibility_tolerance);
        }
    }
    FormFactors { rows, stats }
}
