//! The visible fraction of a pair of patches, from jittered shadow rays on a uniform grid of
//! blocks.
//!
//! The pair's exchange `∫_{P_i'} ∫_{P_j'} K(x, y) V(x, y) dA_y dA_x` (`K` the form-factor kernel
//! `cos θ_x cos θ_y / (π r²)`, `V` the 0/1 visibility) is split into blocks `b = (t, c)`: `t` a
//! triangle of `P_i'`, `c` one of `P_j'`, cut from the fan triangles of the clipped polygons by
//! `L` rounds of midpoint subdivision, each round splitting every block on the side with the
//! longer edges. Each block gets one ray between a uniform point of `t` and a uniform point of
//! `c` (jittered stratification, the points from a [`Stream`] keyed by the pair and `L`), and
//! the weight `u_b = A_t F_{centroid(t)→c}` (its unoccluded exchange, scene units², with the
//! exact point-to-polygon form factor). The visible fraction is the ratio estimate
//! `φ = Σ_b u_b V_b / Σ_b u_b`, so a pair whose rays are all unblocked has `φ = 1` exactly.
//!
//! Why uniform and jittered: refining only blocks whose rays disagree biases the estimate (a
//! block whose rays agree keeps the lit or shadowed island they missed, and all such errors
//! have the sign of the block's verdict), and rays through block centroids line up with the
//! shadow edges of axis-aligned scenes, so their errors add up instead of cancelling. Jittered
//! rays on a uniform grid make the error that of stratified sampling: for a shadow boundary
//! crossing the four-dimensional domain, `O(N^(-5/8))` for `N` blocks.
//!
//! The error of `φ` is the standard deviation of the ratio estimate under the jitter, estimated
//! by collapsing the strata in fours (the children of one parent block):
//! `Var φ ≈ (4/3) Σ_parents Σ_k (y_k - ȳ)² / (Σ_b u_b)²` with `y_b = u_b (V_b - φ)` and `ȳ` the
//! mean over the siblings. This overestimates a little (by the spread of the siblings' true
//! means), and is floored at `sqrt(p (1 - p)) N^(-3/4) / 2` with `p = (n_lit + 1/2) / (N + 1)`
//! (`n_lit` unblocked rays of `N`), so that a grid whose rays all agree, in a pair known to be
//! partly visible, does not stop the refinement. The errors of different pairs come from
//! independent jitter: rows add them in quadrature.
//!
//! The probe of a pair adds rays between its corners (each moved `1e-3` of the way to its
//! polygon's centroid): for two parallel polygons and a convex blocker, if all corner rays are
//! blocked then so is every ray, so these catch the thin penumbrae at the rim of a shadow that
//! a coarse grid misses.

use super::form_factor::contour;
use super::quadrature::split;
use crate::rng::Stream;
use glam::{DVec3, Vec3};
use mcrad_raycast::{RayCaster, SurfacePoint};

/// One side of a pair: a patch id and its unit normal (f64 for the weights, f32 for the rays).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Side {
    pub id: u32,
    pub normal: DVec3,
    pub normal32: Vec3,
}

/// How far corners move towards their polygon's centroid for the probe rays.
const CORNER_INSET: f64 = 1e-3;

fn centroid(t: &[DVec3; 3]) -> DVec3 {
    (t[0] + t[1] + t[2]) / 3.0
}

fn area(t: &[DVec3; 3]) -> f64 {
    0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()
}

fn longest_edge(t: &[DVec3; 3]) -> f64 {
    t[0].distance(t[1])
        .max(t[1].distance(t[2]))
        .max(t[2].distance(t[0]))
}

/// The fan triangles of a convex polygon with positive area.
pub(crate) fn fan(poly: &[DVec3]) -> impl Iterator<Item = [DVec3; 3]> + '_ {
    (1..poly.len().saturating_sub(1))
        .map(move |k| [poly[0], poly[k], poly[k + 1]])
        .filter(|t| area(t) > 0.0)
}

/// A uniform point of triangle `t` from two uniforms (density `1/A_t`).
fn point_in(t: &[DVec3; 3], u1: f64, u2: f64) -> DVec3 {
    let s = u1.sqrt();
    t[0] + (t[1] - t[0]) * (s * (1.0 - u2)) + (t[2] - t[0]) * (s * u2)
}

/// The grid of one pair: the root blocks and which side each round splits.
#[derive(Debug)]
pub(crate) struct Grid {
    source: Side,
    target: Side,
    roots: Vec<([DVec3; 3], [DVec3; 3])>,
    /// `split_source[r]`: round `r + 1` splits the source side.
    split_source: Vec<bool>,
    /// Stream item of the pair.
    key: u64,
}

/// One grid's estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Visibility {
    /// Blocks (one ray each).
    pub blocks: usize,
    /// Rays that were unblocked.
    pub lit: usize,
    /// The visible fraction `φ` (1 when all rays are unblocked, 0 when none is).
    pub fraction: f64,
    /// Its estimated error (module documentation).
    pub error: f64,
    /// Point-to-polygon form factors evaluated for the weights.
    pub evaluations: u64,
}

impl Grid {
    /// The grid of the pair `source_polygon` (`P_i'`) and `target_polygon` (`P_j'`), with
    /// stream key `key` (unique per pair), for up to `max_rounds` rounds of splitting.
    pub fn new(
        source: Side,
        source_polygon: &[DVec3],
        target: Side,
        target_polygon: &[DVec3],
        key: u64,
        max_rounds: usize,
    ) -> Grid {
        let mut roots = Vec::new();
        for t in fan(source_polygon) {
            for c in fan(target_polygon) {
                roots.push((t, c));
            }
        }
        let size = |f: fn(&([DVec3; 3], [DVec3; 3])) -> &[DVec3; 3]| {
            roots.iter().map(|r| longest_edge(f(r))).fold(0.0, f64::max)
        };
        let (mut s, mut c) = (size(|r| &r.0), size(|r| &r.1));
        let split_source = (0..max_rounds)
            .map(|_| {
                let source_side = s >= c;
                if source_side {
                    s *= 0.5;
                } else {
                    c *= 0.5;
                }
                source_side
            })
            .collect();
        Grid {
            source,
            target,
            roots,
            split_source,
            key,
        }
    }

    /// Blocks after `rounds` rounds.
    pub fn blocks(&self, rounds: usize) -> usize {
        self.roots.len() << (2 * rounds)
    }

    /// The fewest rounds (at least 1) that give at least `blocks` blocks.
    pub fn rounds_for(&self, blocks: usize) -> usize {
        (1..self.split_source.len())
            .find(|&r| self.blocks(r) >= blocks)
            .unwrap_or(self.split_source.len())
    }

    /// The most rounds this grid was made for.
    pub fn max_rounds(&self) -> usize {
        self.split_source.len()
    }

    fn surface_points(&self, x: DVec3, y: DVec3) -> (SurfacePoint, SurfacePoint) {
        (
            SurfacePoint::new(x.as_vec3(), self.source.normal32, self.source.id),
            SurfacePoint::new(y.as_vec3(), self.target.normal32, self.target.id),
        )
    }

    /// Rays between the (inset) corners of the two polygons: `(unblocked, cast)`.
    pub fn probe_corners<C: RayCaster>(
        &self,
        caster: &C,
        source_polygon: &[DVec3],
        target_polygon: &[DVec3],
    ) -> (usize, usize) {
        let inset = |poly: &[DVec3]| -> Vec<DVec3> {
            let c = poly.iter().sum::<DVec3>() / poly.len() as f64;
            poly.iter().map(|v| *v + (c - *v) * CORNER_INSET).collect()
        };
        let (xs, ys) = (inset(source_polygon), inset(target_polygon));
        let mut lit = 0;
        for x in &xs {
            for y in &ys {
                let (a, b) = self.surface_points(*x, *y);
                lit += usize::from(!caster.occluded(&a, &b));
            }
        }
        (lit, xs.len() * ys.len())
    }

    /// The estimate after `rounds` rounds of splitting (`>= 1`): one jittered ray per block.
    /// With `weigh == false` only the rays are cast (a probe): `fraction` is then the plain
    /// fraction of unblocked rays and `error` 0.
    pub fn estimate<C: RayCaster>(&self, caster: &C, rounds: usize, weigh: bool) -> Visibility {
        let rounds = rounds.clamp(1, self.split_source.len().max(1));
        let mut rng = Stream::new(0, rounds as u64, self.key, 0);
        let mut acc = Accumulator::default();
        for (t, c) in &self.roots {
            self.visit(caster, &mut rng, &mut acc, *t, *c, 0, rounds, weigh);
        }
        let blocks = acc.blocks;
        let p = (acc.lit as f64 + 0.5) / (blocks as f64 + 1.0);
        let floor = (p * (1.0 - p)).sqrt() * (blocks as f64).powf(-0.75) / 2.0;
        let fraction = match acc.lit {
            0 => 0.0,
            l if l == blocks => 1.0,
            l if !weigh || !(acc.u > 0.0) => l as f64 / blocks as f64,
            _ => (acc.uv / acc.u).clamp(0.0, 1.0),
        };
        let error = if !weigh {
            0.0
        } else if acc.u > 0.0 {
            // Collapsed strata over siblings: v = (4/3) Σ_parents Σ_k (y_k - ȳ)², with
            // y_k = u_k (V_k - φ), expanded in the sums kept per parent.
            let f = fraction;
            let within = acc.uuv * (1.0 - 2.0 * f) + f * f * acc.uu;
            let means = (acc.parent_uv2 - 2.0 * f * acc.parent_uv_u + f * f * acc.parent_u2) / 4.0;
            let v = (4.0 / 3.0) * (within - means).max(0.0);
            (v.sqrt() / acc.u).max(floor)
        } else {
            floor
        };
        Visibility {
            blocks,
            lit: acc.lit,
            fraction,
            error,
            evaluations: acc.evaluations,
        }
    }

    #[allow(clippy::too_many_arguments)]
    fn visit<C: RayCaster>(
        &self,
        caster: &C,
        rng: &mut Stream,
        acc: &mut Accumulator,
        t: [DVec3; 3],
        c: [DVec3; 3],
        depth: usize,
        rounds: usize,
        weigh: bool,
    ) {
        let children: [([DVec3; 3], [DVec3; 3]); 4] = if self.split_source[depth] {
            split(&t).map(|t| (t, c))
        } else {
            split(&c).map(|c| (t, c))
        };
        if depth + 1 < rounds {
            for (t, c) in children {
                self.visit(caster, rng, acc, t, c, depth + 1, rounds, weigh);
            }
            return;
        }
        // The children are blocks: one ray each, and the sums of this parent.
        let (mut su, mut suv) = (0.0, 0.0);
        for (t, c) in &children {
            let x = point_in(t, rng.uniform_f64(), rng.uniform_f64());
            let y = point_in(c, rng.uniform_f64(), rng.uniform_f64());
            let (a, b) = self.surface_points(x, y);
            let lit = !caster.occluded(&a, &b);
            acc.blocks += 1;
            acc.lit += usize::from(lit);
            if weigh {
                let u = area(t) * contour(centroid(t), self.source.normal, c);
                let uv = if lit { u } else { 0.0 };
                acc.evaluations += 1;
                su += u;
                suv += uv;
                acc.uu += u * u;
                acc.uuv += u * uv;
            }
        }
        acc.u += su;
        acc.uv += suv;
        acc.parent_u2 += su * su;
        acc.parent_uv2 += suv * suv;
        acc.parent_uv_u += suv * su;
    }
}

/// Sums over the blocks of a grid (`u` the weights, `V` the 0/1 ray results) and over their
/// parents (`U_p = Σ_{k} u_k`, `W_p = Σ_k u_k V_k` over a parent's four children).
#[derive(Debug, Default)]
struct Accumulator {
    blocks: usize,
    lit: usize,
    evaluations: u64,
    /// `Σ u`, `Σ u V`, `Σ u²`, `Σ u² V`.
    u: f64,
    uv: f64,
    uu: f64,
    uuv: f64,
    /// `Σ_p U_p²`, `Σ_p W_p²`, `Σ_p W_p U_p`.
    parent_u2: f64,
    parent_uv2: f64,
    parent_uv_u: f64,
}
