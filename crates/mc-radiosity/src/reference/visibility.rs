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
//! The error of `φ` is estimated from the four interleaved sub-grids of the last round (the
//! `k`-th children of every parent, `k = 0..3`), independent stratified designs at the
//! parent's resolution: with `φ_k` their estimates and `s` their standard deviation, the error
//! of the whole grid is `s / 2` (the random-group estimate), but at least
//! `sqrt(p (1 - p)) N^(-3/4) / 2` with `p = (n_lit + 1/2) / (N + 1)` (`n_lit` unblocked rays),
//! so that sub-grids that agree by accident, or a grid whose rays all agree in a pair known to
//! be partly visible, do not stop the refinement.
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
            self.visit(caster, &mut rng, &mut acc, *t, *c, 0, rounds, 0, weigh);
        }
        let blocks = acc.blocks;
        let p = (acc.lit as f64 + 0.5) / (blocks as f64 + 1.0);
        let floor = (p * (1.0 - p)).sqrt() * (blocks as f64).powf(-0.75) / 2.0;
        let all: f64 = acc.all.iter().sum();
        let lit_weight: f64 = acc.lit_weight.iter().sum();
        let (fraction, error) = if !weigh || !(all > 0.0) {
            (
                acc.lit as f64 / blocks.max(1) as f64,
                if weigh { floor } else { 0.0 },
            )
        } else {
            let phis: Vec<f64> = (0..4)
                .filter(|&g| acc.all[g] > 0.0)
                .map(|g| acc.lit_weight[g] / acc.all[g])
                .collect();
            let spread = if phis.len() < 2 {
                0.0
            } else {
                let mean = phis.iter().sum::<f64>() / phis.len() as f64;
                (phis.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / (phis.len() - 1) as f64)
                    .sqrt()
            };
            (
                (lit_weight / all).clamp(0.0, 1.0),
                (spread / 2.0).max(floor),
            )
        };
        let (fraction, error) = match acc.lit {
            0 => (0.0, error),
            l if l == blocks => (1.0, error),
            _ => (fraction, error),
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
        group: usize,
        weigh: bool,
    ) {
        if depth == rounds {
            let x = point_in(&t, rng.uniform_f64(), rng.uniform_f64());
            let y = point_in(&c, rng.uniform_f64(), rng.uniform_f64());
            let (a, b) = self.surface_points(x, y);
            let lit = !caster.occluded(&a, &b);
            acc.blocks += 1;
            acc.lit += usize::from(lit);
            if weigh {
                let u = area(&t) * contour(centroid(&t), self.source.normal, &c);
                acc.evaluations += 1;
                acc.all[group] += u;
                if lit {
                    acc.lit_weight[group] += u;
                }
            }
            return;
        }
        if self.split_source[depth] {
            for (k, child) in split(&t).into_iter().enumerate() {
                self.visit(caster, rng, acc, child, c, depth + 1, rounds, k, weigh);
            }
        } else {
            for (k, child) in split(&c).into_iter().enumerate() {
                self.visit(caster, rng, acc, t, child, depth + 1, rounds, k, weigh);
            }
        }
    }
}

#[derive(Debug, Default)]
struct Accumulator {
    blocks: usize,
    lit: usize,
    /// Per sub-grid: `Σ u_b` and `Σ u_b V_b`.
    all: [f64; 4],
    lit_weight: [f64; 4],
    evaluations: u64,
}
