//! Symmetric quadrature rules on triangles, each with an embedded rule of lower degree whose
//! difference from it estimates the error.
//!
//! A rule integrates `∫_T g dA ≈ A_T Σ_k w_k g(λ_k)`, where `λ_k` are barycentric coordinates
//! and the weights sum to 1. The embedded rule uses a prefix of the same points with its own
//! weights, so the error estimate costs no extra evaluation. The estimate `|Q_high - Q_low|` is
//! the error of the *lower* rule: for a smooth integrand it exceeds the error of the value
//! returned (`Q_high`) by a factor `~ (d / h)^(p_high - p_low)`, `h` the triangle's size and `d`
//! the distance at which the integrand varies, so error control built on it is conservative.

// Nodes and weights keep the digits they were computed with; the compiler rounds them.
#![allow(clippy::excessive_precision)]

use glam::DVec3;
use std::cmp::Ordering;
use std::collections::BinaryHeap;

/// A rule: barycentric points, the weights of the high-degree rule, and the weights of the
/// embedded low-degree rule on the first `low.len()` points.
#[derive(Debug)]
pub(crate) struct Rule {
    pub points: &'static [[f64; 3]],
    pub high: &'static [f64],
    pub low: &'static [f64],
}

const C: f64 = 1.0 / 3.0;

const fn orbit3(a: f64) -> [[f64; 3]; 3] {
    let b = 1.0 - 2.0 * a;
    [[a, a, b], [a, b, a], [b, a, a]]
}

const fn orbit6(a: f64, b: f64) -> [[f64; 3]; 6] {
    let c = 1.0 - a - b;
    [
        [a, b, c],
        [a, c, b],
        [b, a, c],
        [b, c, a],
        [c, a, b],
        [c, b, a],
    ]
}

const R7_A1: f64 = 0.101_286_507_323_456_338_8; // (6 - sqrt 15) / 21
const R7_A2: f64 = 0.470_142_064_105_115_089_8; // (6 + sqrt 15) / 21
const R7_W1: f64 = 0.125_939_180_544_827_152_6; // (155 - sqrt 15) / 1200
const R7_W2: f64 = 0.132_394_152_788_506_180_7; // (155 + sqrt 15) / 1200

static R7_POINTS: [[f64; 3]; 7] = {
    let (o1, o2) = (orbit3(R7_A1), orbit3(R7_A2));
    [[C, C, C], o1[0], o1[1], o1[2], o2[0], o2[1], o2[2]]
};

/// Radon's 7-point rule, degree 5, with the degree-2 rule on its centroid and inner orbit
/// (weights `1 - 3w`, `w = 1 / (18 (2a² + b² - 1/3))`, `b = 1 - 2a`).
pub(crate) static RADON7: Rule = Rule {
    points: &R7_POINTS,
    high: &[9.0 / 40.0, R7_W1, R7_W1, R7_W1, R7_W2, R7_W2, R7_W2],
    low: &[
        0.484_122_918_275_927_110_6,
        0.171_959_027_241_357_629_8,
        0.171_959_027_241_357_629_8,
        0.171_959_027_241_357_629_8,
    ],
};

const D_A1: f64 = 0.459_292_588_292_723_156_0;
const D_A2: f64 = 0.170_569_307_751_760_206_6;
const D_A3: f64 = 0.050_547_228_317_030_975_46;
const D_A4: f64 = 0.008_394_777_409_957_605_337;
const D_B4: f64 = 0.263_112_829_634_638_113_4;
const D_W0: f64 = 0.144_315_607_677_787_168_3;
const D_W1: f64 = 0.095_091_634_267_284_624_79;
const D_W2: f64 = 0.103_217_370_534_718_250_3;
const D_W3: f64 = 0.032_458_497_623_198_080_31;
const D_W4: f64 = 0.027_230_314_174_434_994_27;
const E_W0: f64 = 0.038_674_452_381_985_338_25;
const E_W1: f64 = 0.153_622_598_321_245_436_4;
const E_W2: f64 = 0.121_891_925_779_277_831_7;
const E_W3: f64 = 0.044_927_325_105_481_619_19;

static D16_POINTS: [[f64; 3]; 16] = {
    let (o1, o2, o3) = (orbit3(D_A1), orbit3(D_A2), orbit3(D_A3));
    let o4 = orbit6(D_A4, D_B4);
    [
        [C, C, C],
        o1[0],
        o1[1],
        o1[2],
        o2[0],
        o2[1],
        o2[2],
        o3[0],
        o3[1],
        o3[2],
        o4[0],
        o4[1],
        o4[2],
        o4[3],
        o4[4],
        o4[5],
    ]
};

/// Dunavant's 16-point rule, degree 8 (nodes polished to f64 precision), with the degree-4
/// rule on its centroid and three 3-orbits (weights solved from the moments of degree 0, 2, 3
/// and 4).
pub(crate) static DUNAVANT16: Rule = Rule {
    points: &D16_POINTS,
    high: &[
        D_W0, D_W1, D_W1, D_W1, D_W2, D_W2, D_W2, D_W3, D_W3, D_W3, D_W4, D_W4, D_W4, D_W4, D_W4,
        D_W4,
    ],
    low: &[E_W0, E_W1, E_W1, E_W1, E_W2, E_W2, E_W2, E_W3, E_W3, E_W3],
};

/// The integral of `g` over the triangle `tri` and its error estimate, both in
/// `[g] × scene units²`: `(A_T Σ w_k g_k, A_T |Σ w_k g_k - Σ w'_k g_k|)`.
#[inline]
pub(crate) fn integrate(
    rule: &Rule,
    tri: &[DVec3; 3],
    mut g: impl FnMut(DVec3) -> f64,
) -> (f64, f64) {
    let area = 0.5 * (tri[1] - tri[0]).cross(tri[2] - tri[0]).length();
    let (mut high, mut low) = (0.0, 0.0);
    for (k, l) in rule.points.iter().enumerate() {
        let v = g(tri[0] * l[0] + tri[1] * l[1] + tri[2] * l[2]);
        high += rule.high[k] * v;
        if let Some(w) = rule.low.get(k) {
            low += w * v;
        }
    }
    (area * high, area * (high - low).abs())
}

/// Adaptive quadrature of `∫_P g dA` over the convex polygon `polygon` (fan triangles), to
/// an estimated error of at most `relative × |value| + absolute` (units of `g` × area).
///
/// Each fan triangle starts with [`RADON7`]; the triangle with the largest error estimate is
/// refined next, first to [`DUNAVANT16`] on the same triangle, then by splitting it into its
/// four midpoint children with [`DUNAVANT16`] each, down to `4^-max_depth` of its area. At most
/// `max_refinements` refinements are made. Returns the value, the error estimate (the sum of
/// the triangles' estimates) and the number of evaluations of `g`.
pub(crate) fn integrate_adaptive(
    polygon: &[DVec3],
    relative: f64,
    absolute: f64,
    max_depth: u8,
    max_refinements: usize,
    mut g: impl FnMut(DVec3) -> f64,
) -> Adaptive {
    let mut regions: Vec<Region> = Vec::new();
    let mut evaluations = 0;
    for k in 1..polygon.len().saturating_sub(1) {
        let tri = [polygon[0], polygon[k], polygon[k + 1]];
        let (value, error) = integrate(&RADON7, &tri, &mut g);
        evaluations += RADON7.points.len() as u64;
        regions.push(Region {
            tri,
            stage: 0,
            depth: 0,
            value,
            error,
            active: true,
        });
    }
    let mut heap: BinaryHeap<Key> = regions
        .iter()
        .enumerate()
        .map(|(k, r)| Key(r.error, k as u32))
        .collect();
    let (mut value, mut error) = regions
        .iter()
        .fold((0.0, 0.0), |(v, e), r| (v + r.value, e + r.error));
    let mut refinements = 0;
    while error > relative * value.abs() + absolute && refinements < max_refinements {
        let Some(Key(_, k)) = heap.pop() else {
            break;
        };
        let r = regions[k as usize].clone();
        if r.stage == 1 && r.depth >= max_depth {
            continue;
        }
        refinements += 1;
        regions[k as usize].active = false;
        value -= r.value;
        error -= r.error;
        let children: Vec<([DVec3; 3], u8)> = if r.stage == 0 {
            vec![(r.tri, r.depth)]
        } else {
            split(&r.tri).map(|t| (t, r.depth + 1)).to_vec()
        };
        for (tri, depth) in children {
            let (v, e) = integrate(&DUNAVANT16, &tri, &mut g);
            evaluations += DUNAVANT16.points.len() as u64;
            value += v;
            error += e;
            heap.push(Key(e, regions.len() as u32));
            regions.push(Region {
                tri,
                stage: 1,
                depth,
                value: v,
                error: e,
                active: true,
            });
        }
    }
    // Exact sums over the active triangles, in a fixed order.
    let (value, error) = regions
        .iter()
        .filter(|r| r.active)
        .fold((0.0, 0.0), |(v, e), r| (v + r.value, e + r.error));
    Adaptive {
        value,
        error,
        evaluations,
    }
}

/// The result of [`integrate_adaptive`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Adaptive {
    /// The integral (units of `g` × area).
    pub value: f64,
    /// Its error estimate (conservative: the lower rules' differences).
    pub error: f64,
    /// Evaluations of the integrand.
    pub evaluations: u64,
}

/// A triangle of [`integrate_adaptive`].
#[derive(Debug, Clone)]
struct Region {
    tri: [DVec3; 3],
    /// 0: Radon's rule; 1: Dunavant's.
    stage: u8,
    depth: u8,
    value: f64,
    error: f64,
    active: bool,
}

/// A heap key: largest value first, then lowest index (deterministic).
#[derive(Debug, PartialEq)]
pub(crate) struct Key(pub f64, pub u32);

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

/// The four midpoint children of a triangle: the three corner triangles (at `a`, `b`, `c`)
/// and the middle one, whose centroid is the parent's.
pub(crate) fn split(t: &[DVec3; 3]) -> [[DVec3; 3]; 4] {
    let [a, b, c] = *t;
    let (ab, bc, ca) = ((a + b) * 0.5, (b + c) * 0.5, (c + a) * 0.5);
    [[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `∫_T λ1^p λ2^q dA / A_T = 2 p! q! / (p + q + 2)!`.
    fn moment(p: u32, q: u32) -> f64 {
        let f = |n: u32| (1..=n).map(f64::from).product::<f64>();
        2.0 * f(p) * f(q) / f(p + q + 2)
    }

    fn max_error(points: &[[f64; 3]], weights: &[f64], degree: u32) -> f64 {
        let mut worst: f64 = 0.0;
        for p in 0..=degree {
            for q in 0..=degree - p {
                let s: f64 = points
                    .iter()
                    .zip(weights)
                    .map(|(l, w)| w * l[0].powi(p as i32) * l[1].powi(q as i32))
                    .sum();
                worst = worst.max((s - moment(p, q)).abs());
            }
        }
        worst
    }

    #[test]
    fn rules_integrate_polynomials_of_their_degree_exactly() {
        for (rule, high, low) in [(&RADON7, 5, 2), (&DUNAVANT16, 8, 4)] {
            assert!(max_error(rule.points, rule.high, high) < 1e-15);
            assert!(max_error(rule.points, rule.high, high + 1) > 1e-8);
            assert!(max_error(&rule.points[..rule.low.len()], rule.low, low) < 1e-15);
            assert!(max_error(&rule.points[..rule.low.len()], rule.low, low + 1) > 1e-6);
            for l in rule.points {
                assert!((l.iter().sum::<f64>() - 1.0).abs() < 1e-15);
                assert!(l.iter().all(|x| *x > 0.0));
            }
        }
    }

    #[test]
    fn integrate_scales_by_area() {
        let tri = [
            DVec3::ZERO,
            DVec3::new(2.0, 0.0, 0.0),
            DVec3::new(0.0, 3.0, 1.0),
        ];
        let (v, e) = integrate(&DUNAVANT16, &tri, |x| x.x * x.x);
        // ∫ x² over the triangle: area * E[x²], x = 2 λ1, E[λ1²] = 1/6.
        let area = 0.5 * (tri[1] - tri[0]).cross(tri[2] - tri[0]).length();
        assert!((v - area * 4.0 / 6.0).abs() < 1e-14);
        assert!(e < 1e-14);
    }
}
