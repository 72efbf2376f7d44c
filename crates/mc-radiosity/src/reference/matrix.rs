//! Form-factor rows: adaptive quadrature of the exact point-to-polygon form factor over the
//! source patch, times a visibility fraction refined by shadow rays.
//!
//! Row `i` holds `F_ij = (1/A_i) ∫_{P_i} F_{x→P_j} v(x, j) dA_x` for every patch `j`. Per pair:
//!
//! 1. **Horizons.** Only `P_j' = P_j ∩ {front of P_i}` can be seen from `P_i`, and only from
//!    `P_i' = P_i ∩ {front of P_j}` (a patch receives on its front only). Both are clipped once;
//!    an empty one makes `F_ij = 0`, as does a shared input face (coplanar patches).
//! 2. **Probe.** Shadow rays between stratified points of `P_i'` and `P_j'` (at least 16 per
//!    pair, 4 per pair of fan triangles) classify the pair: all unblocked, visible (`v = 1`);
//!    all blocked, hidden (`F_ij = 0`); otherwise partly visible.
//! 3. **Quadrature** of `U_ij = ∫_{P_i'} F_{x→P_j'} dA_x` with the exact contour form factor as
//!    integrand, on the fan triangles of `P_i'`: Radon's degree-5 rule first, then Dunavant's
//!    degree-8 rule, then the degree-8 rule on the four midpoint children, recursively (the
//!    integrand is smooth except at vertices `P_i'` shares with `P_j'`). Each triangle carries
//!    the conservative estimate `|Q_high - Q_low|` of its embedded pair of rules.
//! 4. **Visibility** of a partly visible pair is `φ_ij = Σ_b u_b f_b / Σ_b u_b` over blocks
//!    `b = (t, c)`, `t` a triangle of `P_i'`, `c` one of `P_j'`, with weight
//!    `u_b = A_t F_{centroid(t)→c}` (the unoccluded exchange, so a pair whose rays are all
//!    unblocked comes out exactly `U_ij`) and `f_b` the fraction of its 4 rays (sub-triangle
//!    centroids of `t` to those of `c`, paired as a Latin square) that are unblocked. A block
//!    whose rays disagree is split (the side with the longer edge, into 4) and probed again.
//!    Its error is estimated as `u_b sqrt(f (1 - f) / k)` (scaled to form-factor units), and
//!    the errors of different blocks are combined as independent (root of the sum of squares):
//!    a shadow boundary crosses each block at an unrelated place.
//!
//! `F_ij = φ_ij U_ij / A_i`. The row's error estimate is `Σ_j φ_j err(U_ij) / A_i` (quadrature,
//! conservative) plus the visibility term; refinement is greedy, always the triangle or block
//! with the largest estimate in the row, until each part is below half the tolerance times
//! the row sum `S_i = Σ_j F_ij`, or a depth or work limit is reached (counted in the stats).
//!
//! What the error estimate cannot see: a blocker that no probe ray of a pair meets (a thin
//! object between the rays, about a quarter of a patch apart), and a gap between blockers that
//! none passes through.

use super::ReferenceError;
use super::form_factor::{clip_above, contour};
use super::quadrature::{DUNAVANT16, RADON7, integrate};
use glam::{DVec3, Vec3};
use mcrad_meshing::Mesh;
use mcrad_raycast::{RayCaster, SurfacePoint};
use rayon::prelude::*;
use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::ops::Range;
use std::sync::atomic::{self, AtomicUsize};

/// Deepest quadrature subdivision: a triangle `4^-24` (about `3.6e-15`) of its fan triangle.
const MAX_QUAD_DEPTH: u8 = 24;
/// Deepest visibility block: 16 splits, so each side is cut to about `1/256` of its size.
const MAX_VIS_DEPTH: u8 = 16;
/// Quadrature refinements allowed per row: this plus [`QUAD_REFINEMENTS_PER_PAIR`] per pair.
const QUAD_REFINEMENTS: usize = 1 << 14;
/// See [`QUAD_REFINEMENTS`].
const QUAD_REFINEMENTS_PER_PAIR: usize = 64;
/// Visibility rays allowed per row: this plus [`VIS_RAYS_PER_PAIR`] per partly visible pair.
const VIS_RAYS: u64 = 1 << 14;
/// See [`VIS_RAYS`].
const VIS_RAYS_PER_PAIR: u64 = 4096;

/// A sparse form-factor matrix: for each patch `i` (mesh order) the patches `j` with
/// `F_ij > 0`, ascending, and the form factors (dimensionless, `Σ_j F_ij <= 1`, equal to 1 in a
/// closed scene). Zeros are not stored.
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

/// Work and accuracy of a form-factor computation.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct FormFactorStats {
    /// Shadow rays cast (probes and visibility refinement).
    pub rays: u64,
    /// Point-to-polygon form factors evaluated (quadrature nodes and visibility weights).
    pub evaluations: u64,
    /// Non-zero entries kept.
    pub nonzeros: usize,
    /// Ordered pairs `(i, j)` found partly visible by their probe rays.
    pub partly_visible_pairs: u64,
    /// The largest estimated error of a row relative to its sum, over rows with a positive
    /// sum: `max_i (err_quadrature_i + err_visibility_i) / S_i`.
    pub max_row_error: f64,
    /// Rows whose estimated error stayed above the tolerance because a depth or work limit
    /// was reached.
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

    /// `y_i = Σ_j F_ij x_j` for row `i` (per RGB channel).
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
/// `tolerance` is the target error of each row relative to its sum (see the module
/// documentation for how it is estimated). `progress` is called with the number of rows done
/// after each row, from the worker threads. Rows are computed in parallel on the current rayon
/// pool; the result does not depend on the thread count.
pub fn form_factors<C: RayCaster>(
    mesh: &Mesh,
    caster: &C,
    tolerance: f64,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<FormFactors, ReferenceError> {
    if !(tolerance > 0.0 && tolerance < 1.0) {
        return Err(ReferenceError::BadTolerance(tolerance));
    }
    let n = mesh.patches().len();
    if n >= u32::MAX as usize {
        return Err(ReferenceError::TooManyPatches {
            patches: n,
            limit: u32::MAX as usize - 1,
        });
    }
    let geometry = Geometry::new(mesh);
    let done = AtomicUsize::new(0);
    let rows: Vec<(Row, RowStats)> = (0..n)
        .into_par_iter()
        .map(|i| {
            let row = RowWork::new(i, &geometry, caster, tolerance).run();
            progress(done.fetch_add(1, atomic::Ordering::Relaxed) + 1);
            row
        })
        .collect();
    let mut stats = FormFactorStats::default();
    for (row, s) in &rows {
        stats.rays += s.rays;
        stats.evaluations += s.evaluations;
        stats.nonzeros += row.cols.len();
        stats.partly_visible_pairs += s.partial;
        stats.max_row_error = stats.max_row_error.max(s.relative_error);
        stats.rows_over_tolerance += usize::from(s.relative_error > tolerance);
    }
    Ok(FormFactors {
        rows: rows.into_iter().map(|(r, _)| r).collect(),
        stats,
    })
}

/// Patch polygons and planes in f64.
struct Geometry {
    corners: Vec<DVec3>,
    first: Vec<usize>,
    normal: Vec<DVec3>,
    normal32: Vec<Vec3>,
    offset: Vec<f64>,
    area: Vec<f64>,
    face: Vec<u32>,
    /// Signed distances to a plane within this are "on the plane" (scene units): rounding of
    /// f32 vertices and of planes fitted to them.
    eps: f64,
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
            face: Vec::new(),
            eps: 0.0,
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
            g.face.push(p.face);
        }
        if lo.x.is_finite() {
            let magnitude = lo.abs().max(hi.abs()).max_element();
            g.eps = 1e-6 * (hi - lo).length() + 1e-7 * magnitude;
        }
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

/// Work and accuracy of one row.
#[derive(Debug, Default)]
struct RowStats {
    rays: u64,
    evaluations: u64,
    partial: u64,
    relative_error: f64,
}

/// One source-target pair of a row.
#[derive(Debug)]
struct Pair {
    j: u32,
    /// `P_i'`: the source clipped to the front of the target, in `RowWork::pool`.
    src: Range<usize>,
    /// `P_j'`: the target clipped to the front of the source, in `RowWork::pool`.
    dst: Range<usize>,
    /// Visible fraction `φ` (1: unoccluded, 0: hidden).
    phi: f64,
    /// Some probe rays were blocked and some not: `φ` comes from the blocks.
    partial: bool,
    /// `U_ij = ∫_{P_i'} F_{x→P_j'} dA_x` (scene units²) and its error estimate.
    integral: f64,
    error: f64,
    /// Visibility weights `Σ u_b` and `Σ u_b f_b` over the pair's blocks (scene units²).
    sum_u: f64,
    sum_uf: f64,
    /// Form-factor units per unit of block weight, `U_ij / (A_i Σ u_b)` at the start.
    scale: f64,
}

/// A quadrature triangle.
#[derive(Debug, Clone)]
struct Region {
    pair: u32,
    tri: [DVec3; 3],
    /// 0: Radon's rule; 1: Dunavant's.
    stage: u8,
    depth: u8,
    value: f64,
    error: f64,
    active: bool,
}

/// A visibility block: a triangle of `P_i'` and one of `P_j'`.
#[derive(Debug, Clone)]
struct Block {
    pair: u32,
    t: [DVec3; 3],
    c: [DVec3; 3],
    u: f64,
    visible: u32,
    rays: u32,
    depth: u8,
    active: bool,
}

impl Block {
    fn fraction(&self) -> f64 {
        self.visible as f64 / self.rays as f64
    }

    fn mixed(&self) -> bool {
        self.visible != 0 && self.visible != self.rays
    }
}

/// A heap key: largest value first, then lowest index (deterministic).
#[derive(Debug, PartialEq)]
struct Key(f64, u32);

impl Eq for Key {}

impl Ord for Key {
    fn cmp(&self, other: &Self) -> Ordering {
        self.0
            .total_cmp(&other.0)
            .then_with(|| other.1.cmp(&self.1))
    }
}

impl PartialOrd for Key {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Everything one row needs.
struct RowWork<'a, C> {
    i: usize,
    g: &'a Geometry,
    caster: &'a C,
    tolerance: f64,
    pool: Vec<DVec3>,
    pairs: Vec<Pair>,
    regions: Vec<Region>,
    blocks: Vec<Block>,
    stats: RowStats,
}

fn fan(poly: &[DVec3]) -> impl Iterator<Item = [DVec3; 3]> + '_ {
    (1..poly.len().saturating_sub(1))
        .map(move |k| [poly[0], poly[k], poly[k + 1]])
        .filter(|t| area(t) > 0.0)
}

#[inline]
fn area(t: &[DVec3; 3]) -> f64 {
    0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()
}

#[inline]
fn centroid(t: &[DVec3; 3]) -> DVec3 {
    (t[0] + t[1] + t[2]) / 3.0
}

/// The four midpoint children of a triangle.
fn split(t: &[DVec3; 3]) -> [[DVec3; 3]; 4] {
    let [a, b, c] = *t;
    let (ab, bc, ca) = ((a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5);
    [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
}

/// The centroids of the four midpoint children of a triangle (its stratified points).
fn strata(t: &[DVec3; 3]) -> [DVec3; 4] {
    let [a, b, c] = *t;
    [
        (a + b + c) / 3.0,
        (4.0 * a + b + c) / 6.0,
        (a + 4.0 * b + c) / 6.0,
        (a + b + 4.0 * c) / 6.0,
    ]
}

fn longest_edge(t: &[DVec3; 3]) -> f64 {
    t[0].distance_squared(t[1])
        .max(t[1].distance_squared(t[2]))
        .max(t[2].distance_squared(t[0]))
}

impl<'a, C: RayCaster> RowWork<'a, C> {
    fn new(i: usize, g: &'a Geometry, caster: &'a C, tolerance: f64) -> Self {
        RowWork {
            i,
            g,
            caster,
            tolerance,
            pool: Vec::new(),
            pairs: Vec::new(),
            regions: Vec::new(),
            blocks: Vec::new(),
            stats: RowStats::default(),
        }
    }

    fn area_i(&self) -> f64 {
        self.g.area[self.i]
    }

    fn run(mut self) -> (Row, RowStats) {
        self.find_pairs();
        self.probe_pairs();
        self.start_quadrature();
        self.refine_quadrature();
        self.start_visibility();
        self.refine_visibility();
        // The visible fractions moved: check the quadrature budget with the final ones.
        self.refine_quadrature();
        self.finish()
    }

    /// Step 1: the pairs that can exchange light at all, with both polygons clipped.
    fn find_pairs(&mut self) {
        let (g, i) = (self.g, self.i);
        let eps = g.eps;
        let mut scratch = Vec::new();
        for j in 0..g.area.len() {
            if j == i || g.face[j] == g.face[i] {
                continue;
            }
            let (src, dst) = (g.polygon(i), g.polygon(j));
            if !dst.iter().any(|v| g.height(i, *v) > eps)
                || !src.iter().any(|v| g.height(j, *v) > eps)
            {
                continue;
            }
            let start = self.pool.len();
            clip_above(src, g.normal[j], g.offset[j], eps, &mut scratch);
            self.pool.extend_from_slice(&scratch);
            let mid = self.pool.len();
            clip_above(dst, g.normal[i], g.offset[i], eps, &mut scratch);
            self.pool.extend_from_slice(&scratch);
            let end = self.pool.len();
            self.pairs.push(Pair {
                j: j as u32,
                src: start..mid,
                dst: mid..end,
                phi: 1.0,
                partial: false,
                integral: 0.0,
                error: 0.0,
                sum_u: 0.0,
                sum_uf: 0.0,
                scale: 0.0,
            });
        }
    }

    /// Casts `shifts.len() × 4` rays between the strata of `t` (on `P_i`) and `c` (on `P_j`);
    /// returns how many are unblocked.
    fn probe(&mut self, j: usize, t: &[DVec3; 3], c: &[DVec3; 3], shifts: &[usize]) -> u32 {
        let (from, to) = (strata(t), strata(c));
        let (ni, nj) = (self.g.normal32[self.i], self.g.normal32[j]);
        let mut visible = 0;
        for &s in shifts {
            for (k, p) in from.iter().enumerate() {
                let a = SurfacePoint::new(p.as_vec3(), ni, self.i as u32);
                let b = SurfacePoint::new(to[(k + s) % 4].as_vec3(), nj, j as u32);
                visible += u32::from(!self.caster.occluded(&a, &b));
            }
        }
        self.stats.rays += 4 * shifts.len() as u64;
        visible
    }

    /// Step 2: classify each pair by at least 16 rays; partly visible pairs keep their blocks.
    fn probe_pairs(&mut self) {
        let ni = self.g.normal[self.i];
        for p in 0..self.pairs.len() {
            let pair = &self.pairs[p];
            let j = pair.j as usize;
            let src: Vec<[DVec3; 3]> = fan(&self.pool[pair.src.clone()]).collect();
            let dst: Vec<[DVec3; 3]> = fan(&self.pool[pair.dst.clone()]).collect();
            let shifts: &[usize] = match src.len() * dst.len() {
                0 => &[],
                1 => &[0, 1, 2, 3],
                2 | 3 => &[1, 3],
                _ => &[1],
            };
            let first = self.blocks.len();
            let (mut visible, mut rays) = (0, 0);
            for t in &src {
                for c in &dst {
                    let v = self.probe(j, t, c, shifts);
                    let k = 4 * shifts.len() as u32;
                    visible += v;
                    rays += k;
                    self.blocks.push(Block {
                        pair: p as u32,
                        t: *t,
                        c: *c,
                        u: 0.0,
                        visible: v,
                        rays: k,
                        depth: 0,
                        active: true,
                    });
                }
            }
            let pair = &mut self.pairs[p];
            if visible == rays {
                pair.phi = if rays == 0 { 0.0 } else { 1.0 };
                self.blocks.truncate(first);
                continue;
            }
            if visible == 0 {
                pair.phi = 0.0;
                self.blocks.truncate(first);
                continue;
            }
            self.stats.partial += 1;
            pair.partial = true;
            let (mut sum_u, mut sum_uf) = (0.0, 0.0);
            for b in &mut self.blocks[first..] {
                b.u = area(&b.t) * contour(centroid(&b.t), ni, &b.c);
                sum_u += b.u;
                sum_uf += b.u * b.fraction();
            }
            self.stats.evaluations += (self.blocks.len() - first) as u64;
            pair.sum_u = sum_u;
            pair.sum_uf = sum_uf;
            pair.phi = if sum_u > 0.0 {
                sum_uf / sum_u
            } else {
                visible as f64 / rays as f64
            };
        }
    }

    /// Step 3a: Radon's rule on every fan triangle of every pair that is not hidden.
    fn start_quadrature(&mut self) {
        let ni = self.g.normal[self.i];
        for p in 0..self.pairs.len() {
            let pair = &self.pairs[p];
            if pair.phi == 0.0 {
                continue;
            }
            let dst = &self.pool[pair.dst.clone()];
            let (mut value, mut error) = (0.0, 0.0);
            for tri in fan(&self.pool[pair.src.clone()]) {
                let (v, e) = integrate(&RADON7, &tri, |x| contour(x, ni, dst));
                self.stats.evaluations += RADON7.points.len() as u64;
                value += v;
                error += e;
                self.regions.push(Region {
                    pair: p as u32,
                    tri,
                    stage: 0,
                    depth: 0,
                    value: v,
                    error: e,
                    active: true,
                });
            }
            let pair = &mut self.pairs[p];
            pair.integral = value;
            pair.error = error;
        }
    }

    /// `S_i` with the current visible fractions.
    fn row_sum(&self) -> f64 {
        self.pairs.iter().map(|p| p.phi * p.integral).sum::<f64>() / self.area_i()
    }

    /// The quadrature part of the row's error estimate.
    fn quadrature_error(&self) -> f64 {
        self.pairs.iter().map(|p| p.phi * p.error).sum::<f64>() / self.area_i()
    }

    /// Step 3b: refine the triangle with the largest weighted error estimate until the
    /// quadrature error is below half the tolerance of the row sum.
    fn refine_quadrature(&mut self) {
        let ni = self.g.normal[self.i];
        let a_i = self.area_i();
        let mut heap: BinaryHeap<Key> = self
            .regions
            .iter()
            .enumerate()
            .filter(|(_, r)| r.active && r.depth < MAX_QUAD_DEPTH)
            .map(|(k, r)| Key(r.error * self.pairs[r.pair as usize].phi, k as u32))
            .collect();
        let mut sum = self.row_sum();
        let mut error = self.quadrature_error();
        let limit = QUAD_REFINEMENTS + QUAD_REFINEMENTS_PER_PAIR * self.pairs.len();
        let mut refinements = 0;
        while error > 0.5 * self.tolerance * sum && refinements < limit {
            let Some(Key(_, k)) = heap.pop() else {
                break;
            };
            refinements += 1;
            let r = self.regions[k as usize].clone();
            let pair = &self.pairs[r.pair as usize];
            let phi = pair.phi;
            let dst = &self.pool[pair.dst.clone()];
            let children: Vec<([DVec3; 3], u8)> = if r.stage == 0 {
                vec![(r.tri, r.depth)]
            } else {
                split(&r.tri).map(|t| (t, r.depth + 1)).to_vec()
            };
            let (mut value, mut err) = (-r.value, -r.error);
            let first = self.regions.len();
            for (tri, depth) in children {
                let (v, e) = integrate(&DUNAVANT16, &tri, |x| contour(x, ni, dst));
                self.stats.evaluations += DUNAVANT16.points.len() as u64;
                value += v;
                err += e;
                self.regions.push(Region {
                    pair: r.pair,
                    tri,
                    stage: 1,
                    depth,
                    value: v,
                    error: e,
                    active: true,
                });
            }
            self.regions[k as usize].active = false;
            for (idx, child) in self.regions.iter().enumerate().skip(first) {
                if child.depth < MAX_QUAD_DEPTH {
                    heap.push(Key(child.error * phi, idx as u32));
                }
            }
            let pair = &mut self.pairs[r.pair as usize];
            pair.integral += value;
            pair.error += err;
            sum += phi * value / a_i;
            error += phi * err / a_i;
        }
        // Exact sums over the active triangles, in a fixed order.
        for p in &mut self.pairs {
            p.integral = 0.0;
            p.error = 0.0;
        }
        for r in self.regions.iter().filter(|r| r.active) {
            let p = &mut self.pairs[r.pair as usize];
            p.integral += r.value;
            p.error += r.error;
        }
    }

    /// The error estimate of a block in form-factor units (0 when its rays agree).
    fn block_error(&self, b: &Block) -> f64 {
        if !b.mixed() {
            return 0.0;
        }
        let f = b.fraction();
        b.u * self.pairs[b.pair as usize].scale * (f * (1.0 - f) / b.rays as f64).sqrt()
    }

    /// Step 4a: scale of each partly visible pair's block weights.
    fn start_visibility(&mut self) {
        let a_i = self.area_i();
        for p in self.pairs.iter_mut().filter(|p| p.partial && p.sum_u > 0.0) {
            p.scale = p.integral / (a_i * p.sum_u);
        }
    }

    /// Step 4b: split the block with the largest error estimate until the visibility error is
    /// below half the tolerance of the row sum.
    fn refine_visibility(&mut self) {
        if self.blocks.is_empty() {
            return;
        }
        let ni = self.g.normal[self.i];
        let a_i = self.area_i();
        let mut heap: BinaryHeap<Key> = BinaryHeap::new();
        let mut squares = 0.0;
        for (k, b) in self.blocks.iter().enumerate() {
            let e = self.block_error(b);
            squares += e * e;
            if e > 0.0 {
                heap.push(Key(e, k as u32));
            }
        }
        let mut sum = self.row_sum();
        let partial = self.pairs.iter().filter(|p| p.partial).count() as u64;
        let budget = self.stats.rays + VIS_RAYS + VIS_RAYS_PER_PAIR * partial;
        while squares.max(0.0).sqrt() > 0.5 * self.tolerance * sum && self.stats.rays < budget {
            let Some(Key(e, k)) = heap.pop() else {
                break;
            };
            let b = self.blocks[k as usize].clone();
            if b.depth >= MAX_VIS_DEPTH {
                continue;
            }
            let j = self.pairs[b.pair as usize].j as usize;
            let split_source = longest_edge(&b.t) >= longest_edge(&b.c);
            let children: [([DVec3; 3], [DVec3; 3]); 4] = if split_source {
                split(&b.t).map(|t| (t, b.c))
            } else {
                split(&b.c).map(|c| (b.t, c))
            };
            let (mut du, mut duf) = (-b.u, -b.u * b.fraction());
            squares -= e * e;
            self.blocks[k as usize].active = false;
            for (t, c) in children {
                let visible = self.probe(j, &t, &c, &[1]);
                let u = area(&t) * contour(centroid(&t), ni, &c);
                self.stats.evaluations += 1;
                let child = Block {
                    pair: b.pair,
                    t,
                    c,
                    u,
                    visible,
                    rays: 4,
                    depth: b.depth + 1,
                    active: true,
                };
                du += u;
                duf += u * child.fraction();
                let ce = self.block_error(&child);
                squares += ce * ce;
                if ce > 0.0 {
                    heap.push(Key(ce, self.blocks.len() as u32));
                }
                self.blocks.push(child);
            }
            let pair = &mut self.pairs[b.pair as usize];
            let old = pair.phi;
            pair.sum_u += du;
            pair.sum_uf += duf;
            if pair.sum_u > 0.0 {
                pair.phi = (pair.sum_uf / pair.sum_u).clamp(0.0, 1.0);
            }
            sum += (pair.phi - old) * pair.integral / a_i;
        }
        // Exact sums over the active blocks, in a fixed order.
        for p in self.pairs.iter_mut().filter(|p| p.partial) {
            (p.sum_u, p.sum_uf) = (0.0, 0.0);
        }
        for b in self.blocks.iter().filter(|b| b.active) {
            let p = &mut self.pairs[b.pair as usize];
            p.sum_u += b.u;
            p.sum_uf += b.u * b.fraction();
        }
        for p in self.pairs.iter_mut().filter(|p| p.partial && p.sum_u > 0.0) {
            p.phi = (p.sum_uf / p.sum_u).clamp(0.0, 1.0);
        }
    }

    fn visibility_error(&self) -> f64 {
        self.blocks
            .iter()
            .filter(|b| b.active)
            .map(|b| self.block_error(b).powi(2))
            .sum::<f64>()
            .sqrt()
    }

    fn finish(mut self) -> (Row, RowStats) {
        let a_i = self.area_i();
        let mut row = Row::default();
        for p in &self.pairs {
            let f = p.phi * p.integral / a_i;
            if f > 0.0 {
                row.cols.push(p.j);
                row.vals.push(f);
            }
        }
        let sum: f64 = row.vals.iter().sum();
        let error = self.quadrature_error() + self.visibility_error();
        self.stats.relative_error = if sum > 0.0 { error / sum } else { 0.0 };
        (row, self.stats)
    }
}
