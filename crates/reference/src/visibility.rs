//! The visible fraction of a pair of patches whose shaft holds an occluder, from jittered
//! shadow rays on an adaptive partition into blocks.
//!
//! The pair's exchange `∫_{P_i'} ∫_{P_j'} K(x, y) V(x, y) dA_y dA_x` (`K` the form-factor kernel
//! `cos θ_x cos θ_y / (π r²)`, `V` the 0/1 visibility) is split into blocks `b = (t, c)`: `t` a
//! triangle of `P_i'`, `c` one of `P_j'`, cut from the fan triangles of the clipped polygons by
//! midpoint subdivision (a block is split on the side with the longer edges). Each block has
//! the weight `u_b = A_t F_{centroid(t)→c}` (its unoccluded exchange, scene units², with the
//! exact point-to-polygon form factor), and the visible fraction is the ratio estimate
//! `φ = Σ_b u_b V̄_b / Σ_b u_b`, `V̄_b` the fraction of the block's rays that are unblocked.
//!
//! The work runs in sweeps, starting from a uniform grid of at least 16 blocks. A sweep casts
//! two fresh rays per block, each between a uniform point of `t` and one of `c` (jittered
//! stratification; the points come from a [`Stream`] keyed by the pair and the sweep), and
//! estimates `φ` and its error from these rays alone. Then it splits the blocks with the
//! largest expected variance `u_b² p_b (1 - p_b) / 2` (`p_b` from every ray the block and its
//! ancestors have seen) until those split hold 80% of the total. Because the partition of a
//! sweep depends only on earlier sweeps, each sweep's estimate is unbiased for it: refining
//! only where the rays of the same sweep disagree would keep every lit or shadowed island they
//! missed, errors that all have the sign of the block's verdict.
//!
//! The error of `φ` is its standard deviation under the jitter,
//! `sqrt(Σ_b u_b² Var V̄_b) / Σ_b u_b`, with `Var V̄_b = p_b (1 - p_b) / 2` estimated without bias
//! by `(V_1 - V_2)² / 4`. It is floored: when every ray of the sweep agrees, at `1 / (n + 2)` for
//! `n` rays (a lit or blocked fraction that small is as likely as none: the mean of the
//! posterior under a uniform prior); otherwise at `sqrt(p (1 - p)) n^(-3/4) / 2`. Different
//! pairs use independent jitter, so rows add their errors in quadrature.

use super::form_factor::contour;
use super::quadrature::split;
use glam::{DVec3, Vec3};
use mcrad_random::Stream;
use mcrad_raycast::{RayCaster, SurfacePoint};

/// One side of a pair: a patch id and its unit normal (f64 for the weights, f32 for the rays).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Side {
    pub id: u32,
    pub normal: DVec3,
    pub normal32: Vec3,
}

/// The share of the expected variance whose blocks a sweep splits.
const SPLIT_SHARE: f64 = 0.8;

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

/// A block's two triangles: `t` on the source side, `c` on the target side.
type Cell = ([DVec3; 3], [DVec3; 3]);

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
    roots: Vec<Cell>,
    /// `split_source[r]`: round `r + 1` splits the source side.
    split_source: Vec<bool>,
    /// Stream item of the pair.
    key: u64,
}

/// A visibility estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Visibility {
    /// Blocks of the final partition.
    pub blocks: usize,
    /// Rays of the final sweep that were unblocked.
    pub lit: usize,
    /// Rays cast, all sweeps.
    pub rays: u64,
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
        let size = |f: fn(&Cell) -> &[DVec3; 3]| {
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

    /// The blocks of the uniform grid under `(t, c)` after `rounds - depth` more rounds.
    fn uniform(
        &self,
        out: &mut Vec<Cell>,
        t: [DVec3; 3],
        c: [DVec3; 3],
        depth: usize,
        rounds: usize,
    ) {
        if depth == rounds {
            out.push((t, c));
            return;
        }
        if self.split_source[depth] {
            for child in split(&t) {
                self.uniform(out, child, c, depth + 1, rounds);
            }
        } else {
            for child in split(&c) {
                self.uniform(out, t, child, depth + 1, rounds);
            }
        }
    }

    /// One jittered ray of the block `(t, c)`: true when unblocked.
    fn ray<C: RayCaster>(
        &self,
        caster: &C,
        rng: &mut Stream,
        t: &[DVec3; 3],
        c: &[DVec3; 3],
    ) -> bool {
        let x = point_in(t, rng.uniform_f64(), rng.uniform_f64());
        let y = point_in(c, rng.uniform_f64(), rng.uniform_f64());
        let (a, b) = self.surface_points(x, y);
        !caster.occluded(&a, &b)
    }

    /// The visible fraction, refined adaptively from the uniform grid after `rounds` rounds
    /// until its estimated error is at most `target`, the partition would exceed `max_blocks`
    /// blocks, or `max_sweeps` sweeps were made (module documentation).
    pub fn refine<C: RayCaster>(
        &self,
        caster: &C,
        rounds: usize,
        target: f64,
        max_blocks: usize,
        max_sweeps: usize,
    ) -> Visibility {
        let rounds = rounds.clamp(1, self.max_rounds().max(1));
        let mut cells = Vec::new();
        for (t, c) in &self.roots {
            self.uniform(&mut cells, *t, *c, 0, rounds);
        }
        let mut evaluations = cells.len() as u64;
        let mut blocks: Vec<Block> = cells
            .into_iter()
            .map(|(t, c)| Block::new(&self.source, t, c, 0.0, 0.0))
            .collect();
        let mut rays = 0u64;
        let mut sweep = 0u64;
        loop {
            sweep += 1;
            let mut rng = Stream::new(0, sweep, self.key, 1 << 32);
            let (mut all, mut lit_weight, mut lit) = (0.0, 0.0, 0usize);
            for b in &mut blocks {
                let v1 = self.ray(caster, &mut rng, &b.t, &b.c);
                let v2 = self.ray(caster, &mut rng, &b.t, &b.c);
                b.lit = u8::from(v1) + u8::from(v2);
                b.seen_lit += f32::from(b.lit);
                b.seen += 2.0;
                all += b.u;
                lit_weight += b.u * f64::from(b.lit) / 2.0;
                lit += usize::from(b.lit);
            }
            let n = 2 * blocks.len();
            rays += n as u64;
            let fraction = match lit {
                0 => 0.0,
                l if l == n => 1.0,
                l if all.is_nan() || all <= 0.0 => l as f64 / n as f64,
                _ => (lit_weight / all).clamp(0.0, 1.0),
            };
            // Var φ = Σ_b u_b² Var(V̄_b) / (Σ_b u_b)², with Var(V̄_b) = p_b (1 - p_b) / 2
            // estimated without bias by (V1 - V2)² / 4.
            let var: f64 = blocks
                .iter()
                .filter(|b| b.lit == 1)
                .map(|b| b.u * b.u / 4.0)
                .sum();
            // When every ray agrees the grid says nothing about a shadow (or a gap) smaller
            // than its cells: a lit (blocked) fraction of 1 / (n + 2), the mean of its
            // posterior under a uniform prior, is as likely as none.
            let p = (lit as f64 + 0.5) / (n as f64 + 1.0);
            let floor = if lit == 0 || lit == n {
                1.0 / (n as f64 + 2.0)
            } else {
                (p * (1.0 - p)).sqrt() * (n as f64).powf(-0.75) / 2.0
            };
            let error = if all > 0.0 {
                (var.sqrt() / all).max(floor)
            } else {
                floor
            };
            if error <= target || sweep as usize >= max_sweeps || blocks.len() + 3 > max_blocks {
                return Visibility {
                    blocks: blocks.len(),
                    lit,
                    rays,
                    fraction,
                    error,
                    evaluations,
                };
            }
            // Split the blocks with the largest expected variance `u² p (1 - p) / 2`, `p` from
            // every ray the block has seen, until the rest would meet the target.
            let expected: Vec<f64> = blocks.iter().map(Block::expected_variance).collect();
            let mut order: Vec<usize> = (0..blocks.len()).collect();
            order.sort_by(|&a, &b| expected[b].total_cmp(&expected[a]).then(a.cmp(&b)));
            let goal = (target * all).powi(2);
            let total: f64 = expected.iter().sum();
            let share = SPLIT_SHARE;
            let mut projected = total;
            let mut taken = 0.0;
            let room = (max_blocks - blocks.len()) / 3;
            let mut chosen = vec![false; blocks.len()];
            for &k in order.iter().take(room.min(blocks.len())) {
                if chosen.iter().any(|c| *c) && (projected <= goal || taken >= share * total) {
                    break;
                }
                chosen[k] = true;
                taken += expected[k];
                projected -= 0.75 * expected[k];
            }
            let mut next = Vec::with_capacity(blocks.len() + 3 * room);
            for (b, split_it) in blocks.into_iter().zip(chosen) {
                if !split_it {
                    next.push(b);
                    continue;
                }
                let children: [Cell; 4] = if longest_edge(&b.t) >= longest_edge(&b.c) {
                    split(&b.t).map(|t| (t, b.c))
                } else {
                    split(&b.c).map(|c| (b.t, c))
                };
                for (t, c) in children {
                    next.push(Block::new(&self.source, t, c, b.seen_lit, b.seen));
                    evaluations += 1;
                }
            }
            blocks = next;
        }
    }
}

/// A block of an adaptive partition.
#[derive(Debug, Clone)]
struct Block {
    t: [DVec3; 3],
    c: [DVec3; 3],
    /// Weight `u_b = A_t F_{centroid(t)→c}` (scene units²).
    u: f64,
    /// Unblocked rays of the current sweep (0..=2).
    lit: u8,
    /// Rays seen by the block and its ancestors (a quarter of a parent's count each), and the
    /// unblocked ones: the evidence for splitting.
    seen: f32,
    seen_lit: f32,
}

impl Block {
    fn new(source: &Side, t: [DVec3; 3], c: [DVec3; 3], seen_lit: f32, seen: f32) -> Block {
        let u = area(&t) * contour(centroid(&t), source.normal, &c);
        Block {
            t,
            c,
            u,
            lit: 0,
            seen,
            seen_lit,
        }
    }

    /// `u² p (1 - p) / 2` with `p = (seen_lit + 1/2) / (seen + 1)`: the variance this block
    /// adds to `Σ u V̄` with two rays.
    fn expected_variance(&self) -> f64 {
        let p = (f64::from(self.seen_lit) + 0.5) / (f64::from(self.seen) + 1.0);
        self.u * self.u * p * (1.0 - p) / 2.0
    }
}
