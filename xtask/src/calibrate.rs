//! `cargo xtask calibrate [--seeds K] [--rays N] [--cases a,b] [--methods m,n] [--limit S]
//! [--sampler random|qmc] [--out FILE] [--per-patch DIR]`: are the per-patch variances every Monte Carlo method reports true, and are
//! its answers unbiased? (issue 16, item 6.)
//!
//! Cases are built in code ([`CASES`]): closed furnaces (a closed box, every face emitting `E`
//! and reflecting `rho`: exactly `B = E / (1 - rho)` on every patch and channel) at
//! `rho` 0.5, 0.9, 0.99 and 0.999; the rho 0.5 furnace moved 1e7 from the origin (exact as at the
//! origin); a closed room lit by a light of about 1e-4 of its area with ~1.6k small patches,
//! whose exact answer is the reference solver's ([`Method::Reference`]: the room is convex, so
//! its form factors need no visibility and are exact to the quadrature tolerance); and
//! ([`LIT_CASES`], issue 34) rooms lit by lights without a surface, a point light, a spot light,
//! and a sun and a uniform sky through a window, each run solving the scene with its lights
//! (`window`, whose reference is slow, only when `--cases` names it).
//!
//! Every method of `Method::monte_carlo()` runs `K` seeds on every case through
//! the library's solve (`mcrad_solve::solve` on the case's mesh), one run at a time. A run that returns
//! an error or panics (caught by `catch_unwind`) is reported, not fatal; a run still going after
//! `--limit` seconds is stopped by its observer at its next step, reported, and the case's
//! remaining seeds of that method are skipped (a run that never reaches a step is not bounded:
//! the table would then not be written, which is itself the finding). The statistics of the
//! complete runs ([`statistics`]) go to a table on stdout and to `docs/calibration.md`.

use anyhow::{Context, Result, bail};
use glam::{DVec3, Vec3};
use mcrad_mc_radiosity::{Method, ScheduleConfig, StopReason};
use mcrad_meshing::{Mesh, Subdivision};
use mcrad_scene_io::{Face, Material, Scene};
use statrs::distribution::{ChiSquared, ContinuousCDF};
use std::fmt::Write as _;
use std::ops::ControlFlow;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Default seeds per (case, method).
const DEFAULT_SEEDS: u64 = 16;
/// Default rays per run.
const DEFAULT_RAYS: u64 = 200_000;
/// Default wall-clock limit of one run, seconds.
const DEFAULT_LIMIT: f64 = 20.0;

/// The targets.
mod target {
    /// Spread between seeds / reported variance.
    pub const SPREAD: (f64, f64) = (0.67, 1.5);
    /// Mean z².
    pub const Z2: (f64, f64) = (0.7, 1.5);
    /// The power of the mean within this many standard errors of exact.
    pub const POWER_SE: f64 = 3.0;
    /// A power bias below this share of the exact power passes whatever the standard error:
    /// the reference solver's own tolerance (it integrates to 1e-4 of a row's sum), met exactly by methods whose power
    /// has no noise (shooting conserves it).
    pub const POWER_TOLERANCE: f64 = 1e-4;
    /// The rho 0.999 furnace's power within this relative error.
    pub const HIGH_RHO: f64 = 0.01;
    /// Rays used / rays asked.
    pub const BUDGET: (f64, f64) = (0.95, 1.05);
    /// The median spread/reported is judged only where the kurtosis of `z` is at most this
    /// times the seeds `K`, `1 / ln 2` (see [`super::median_judged`]).
    pub const RARE_KURTOSIS_PER_SEED: f64 = std::f64::consts::LOG2_E;
}

/// Whether the median column says anything about the variance: not where errors are made of
/// events so rare that most patches see none in `seeds` runs. An event of probability `p` per
/// run gives `z` a kurtosis of about `1/p`; beyond `K / ln 2` (`p < ln 2 / K`, so
/// `(1 - p)^K > 1/2`) the median patch saw no event in its `K` runs, so its spread between
/// seeds lacks the events that its (true) variance includes, and the median ratio is far below
/// 1 however true the variance (`rare_events_defeat_the_median_not_the_pooled_ratio`). (Until
/// issue 17 the bound was `10 K`, nine patches in ten without an event: quasi-Monte Carlo rays
/// see a small light as often, but no patch twice in a run, which lowers the kurtosis to
/// 30-60 where the median patch still saw nothing.) The pooled ratio, which sums the events of
/// all patches, and mean `z²` stay the checks there.
fn median_judged(stats: &Stats, seeds: u64) -> bool {
    stats
        .z_kurtosis
        .is_none_or(|k| k <= target::RARE_KURTOSIS_PER_SEED * seeds as f64)
}

/// The side of the furnace boxes (scene units). A multiple of 12: the default subdivision
/// (diagonal / 20) cuts each side into 12 patches of side 1, so far from the origin every
/// vertex is still an integer, exact in `f32` up to 2^24.
const FURNACE_SIDE: f32 = 12.0;
/// How far the far furnace is moved along each axis (scene units).
const FAR: f32 = 1e7;

/// A calibration case.
pub struct Case {
    /// The name `--cases` selects.
    pub name: &'static str,
    /// One line on what it is.
    pub what: &'static str,
    /// Builds the scene and its subdivision.
    build: fn() -> (Scene, Subdivision),
    /// The exact answer: a closed furnace's `E / (1 - rho)`, or the reference solver's.
    exact: Exact,
    /// Rays of a run: `--rays` times this.
    rays_factor: u64,
    /// The furnace reflectance when the case is a high-reflectance one (the 1% target applies
    /// at 0.999).
    rho: Option<f64>,
    /// What is judged: the patches of the case's mesh, or the input faces of an adaptive mesh.
    grain: Grain,
}

/// What a case judges.
#[derive(Clone, Copy, PartialEq)]
enum Grain {
    /// Every patch of the case's mesh, the same for every run.
    Patches,
    /// Every input face, as `--per-face` writes it (the area-weighted mean of its patches,
    /// its variance with the correlation between them), each run meshing the scene on the
    /// adaptive plan (its own mesh: refined where its own pilot saw the light vary); the
    /// exact answer is per face from the case's mesh.
    AdaptiveFaces,
}

/// Where a case's exact answer comes from.
#[derive(Clone, Copy, PartialEq)]
enum Exact {
    /// `B_i = E_i / (1 - rho_i)` per patch and channel (a closed furnace).
    Furnace,
    /// The reference solver ([`Method::Reference`]).
    Reference,
}

/// The calibration cases.
pub const CASES: [Case; 12] = [
    Case {
        name: "furnace-0.5",
        what: "closed box, side 12, every face E = 1, rho = 0.5; exact B = 2",
        build: || furnace(0.5, Vec3::ZERO),
        exact: Exact::Furnace,
        rays_factor: 1,
        rho: Some(0.5),
        grain: Grain::Patches,
    },
    Case {
        name: "furnace-0.9",
        what: "closed box, rho = 0.9; exact B = 10",
        build: || furnace(0.9, Vec3::ZERO),
        exact: Exact::Furnace,
        rays_factor: 1,
        rho: Some(0.9),
        grain: Grain::Patches,
    },
    Case {
        name: "furnace-0.99",
        what: "closed box, rho = 0.99; exact B = 100",
        build: || furnace(0.99, Vec3::ZERO),
        exact: Exact::Furnace,
        rays_factor: 1,
        rho: Some(0.99),
        grain: Grain::Patches,
    },
    Case {
        name: "furnace-0.999",
        what: "closed box, rho = 0.999; exact B = 1000",
        build: || furnace(0.999, Vec3::ZERO),
        exact: Exact::Furnace,
        rays_factor: 1,
        rho: Some(0.999),
        grain: Grain::Patches,
    },
    Case {
        name: "furnace-far",
        what: "the rho 0.5 furnace moved by 1e7 along every axis; exact B = 2",
        build: || furnace(0.5, Vec3::splat(FAR)),
        exact: Exact::Furnace,
        rays_factor: 1,
        rho: Some(0.5),
        grain: Grain::Patches,
    },
    Case {
        name: "tiny-light",
        what: "closed 4 x 2.5 x 3 room, a 0.08 x 0.08 light in the ceiling (1.1e-4 of the \
               area), patches of at most 0.2 (~1.6k); exact: the reference solver",
        build: tiny_light_room,
        exact: Exact::Reference,
        rays_factor: 5,
        rho: None,
        grain: Grain::Patches,
    },
    Case {
        name: "slivers",
        what: "closed 2 m cube, one patch per face (no subdivision): every wall cut at 0.25 m \
               with 1 cm strips between some cuts, so 0.25 m squares, 1 cm x 0.25 m slivers and \
               1 cm squares (1014 patches); the light is the 1 cm square at the ceiling's \
               centre (1e-4 m², 2.5e-5 of the area); exact: the reference solver",
        build: slivers_room,
        exact: Exact::Reference,
        rays_factor: 5,
        rho: None,
        grain: Grain::Patches,
    },
    Case {
        name: "textured",
        what: "closed 2 m cube, 0.5 x 0.5 ceiling light, the floor textured by an 8 x 8 \
               orange/blue checker (reflectance per patch from the texture), patches of at \
               most 0.15; exact: the reference solver on the same patches",
        build: textured_room,
        exact: Exact::Reference,
        rays_factor: 2,
        rho: None,
        grain: Grain::Patches,
    },
    // Issue 36, item 1: the bias case of the issue built more faithfully than `slivers`: dim
    // patches far from the light.
    Case {
        name: "slivers-corridor",
        what: "closed 2 x 2 x 8 m corridor, one patch per face: the walls cut as the slivers \
               room's (0.25 m squares, 1 cm x 0.25 m slivers, 1 cm squares), along the 8 m four \
               times over (3042 patches); the light is a 1 cm square at the ceiling's centre \
               over the first 2 m (1e-4 m², 1 W), so the far end is dim; exact: the reference \
               solver",
        build: slivers_corridor,
        exact: Exact::Reference,
        rays_factor: 5,
        rho: None,
        grain: Grain::Patches,
    },
    // Issue 36, item 2: one patch per face (`--no-subdivide`), where a patch's variance has
    // no other patches of its face to pool the quasi-Monte Carlo gain with.
    Case {
        name: "furnace-0.9-faces",
        what: "the rho 0.9 furnace with one patch per face (6 patches, `--no-subdivide`); \
               exact B = 10",
        build: || (furnace(0.9, Vec3::ZERO).0, Subdivision::None),
        exact: Exact::Furnace,
        rays_factor: 1,
        rho: Some(0.9),
        grain: Grain::Patches,
    },
    Case {
        name: "furnace-0.99-faces",
        what: "the rho 0.99 furnace with one patch per face (6 patches, `--no-subdivide`); \
               exact B = 100",
        build: || (furnace(0.99, Vec3::ZERO).0, Subdivision::None),
        exact: Exact::Furnace,
        rays_factor: 1,
        rho: Some(0.99),
        grain: Grain::Patches,
    },
    // Issue 36, items 3 and 5: per-face figures on an adaptive mesh.
    Case {
        name: "tiny-light-faces",
        what: "the tiny-light room on the adaptive plan (each run refines its own mesh), \
               judged per input face (14 faces, `--per-face`: the area-weighted mean of a face's \
               patches, its variance with their correlation); exact: the reference solver on \
               the tiny-light case's patches, per face",
        build: tiny_light_room,
        exact: Exact::Reference,
        rays_factor: 5,
        rho: None,
        grain: Grain::AdaptiveFaces,
    },
];

fn material(name: &str, rho: Vec3, e: f32) -> Material {
    Material {
        name: name.into(),
        reflectance: rho,
        emission: Vec3::splat(e),
    }
}

/// A closed box `[o, o + FURNACE_SIDE]³`, faces inward, all of one material emitting 1 W/m²
/// and reflecting `rho`; default subdivision.
fn furnace(rho: f32, o: Vec3) -> (Scene, Subdivision) {
    let s = FURNACE_SIDE;
    let mut positions = Vec::new();
    for z in [0.0, s] {
        for y in [0.0, s] {
            for x in [0.0, s] {
                positions.push(o + Vec3::new(x, y, z));
            }
        }
    }
    // Vertex (x, y, z) bits: index = x + 2y + 4z. Quads counter-clockwise seen from inside.
    let quads = [
        [1, 3, 2, 0],
        [6, 7, 5, 4],
        [4, 5, 1, 0],
        [3, 7, 6, 2],
        [2, 6, 4, 0],
        [5, 7, 3, 1],
    ];
    let faces = quads
        .iter()
        .enumerate()
        .map(|(k, q)| Face {
            vertices: q.to_vec(),
            material: 0,
            source: k as u32,
        })
        .collect();
    let scene = Scene::new(
        positions,
        faces,
        vec![material("furnace", Vec3::splat(rho), 1.0)],
    )
    .expect("the furnace is a valid scene")
    .0;
    let sub = Subdivision::default_for(&scene);
    (scene, sub)
}

/// Faces being built as rectangles, numbered in order (the calibration rooms).
#[derive(Default)]
struct Rects {
    positions: Vec<Vec3>,
    faces: Vec<Face>,
}

impl Rects {
    /// A rectangle with corners `p`, `p + u`, `p + u + v`, `p + v`, facing `normal`.
    fn add(&mut self, p: Vec3, u: Vec3, v: Vec3, normal: Vec3, material: u32) {
        let mut ring = [p, p + u, p + u + v, p + v];
        if u.cross(v).dot(normal) < 0.0 {
            ring.reverse();
        }
        let base = self.positions.len() as u32;
        self.positions.extend(ring);
        let source = self.faces.len() as u32;
        self.faces.push(Face {
            vertices: (base..base + 4).collect(),
            material,
            source,
        });
    }
}

/// A closed room 4 (x) by 2.5 (y, up) by 3 (z), its ceiling cut into a 3 x 3 grid of
/// rectangles whose centre one is a 0.08 x 0.08 light (E = 1000 W/m², 1.1e-4 of the room's
/// area); coloured walls; patches of at most 0.2.
fn tiny_light_room() -> (Scene, Subdivision) {
    let (w, h, d, l) = (4.0f32, 2.5f32, 3.0f32, 0.08f32);
    let mut r = Rects::default();
    let mut rect = |p, u, v, normal, material| r.add(p, u, v, normal, material);
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    rect(Vec3::ZERO, w * x, d * z, y, 0); // floor
    rect(Vec3::ZERO, d * z, h * y, x, 1); // x = 0
    rect(w * x, d * z, h * y, -x, 2); // x = w, the accent wall
    rect(Vec3::ZERO, w * x, h * y, z, 1); // z = 0
    rect(d * z, w * x, h * y, -z, 1); // z = d
    let xs = [0.0, 0.5 * (w - l), 0.5 * (w + l), w];
    let zs = [0.0, 0.5 * (d - l), 0.5 * (d + l), d];
    for i in 0..3 {
        for k in 0..3 {
            let light = i == 1 && k == 1;
            rect(
                Vec3::new(xs[i], h, zs[k]),
                (xs[i + 1] - xs[i]) * x,
                (zs[k + 1] - zs[k]) * z,
                -y,
                if light { 4 } else { 3 },
            );
        }
    }
    let materials = vec![
        material("floor", Vec3::new(0.45, 0.35, 0.25), 0.0),
        material("wall", Vec3::new(0.7, 0.7, 0.68), 0.0),
        material("accent", Vec3::new(0.3, 0.5, 0.6), 0.0),
        material("ceiling", Vec3::splat(0.8), 0.0),
        material("light", Vec3::ZERO, 1000.0),
    ];
    let scene = Scene::new(r.positions, r.faces, materials)
        .expect("the room is a valid scene")
        .0;
    (scene, Subdivision::MaxEdge(0.2))
}

/// Where the walls of [`slivers_room`] are cut, along each of their two axes (m): 0.25 m
/// apart, with 1 cm strips at 0.25, 0.75, 1.25 and 1.75 and one 1 cm strip at the centre (the
/// light's, on the ceiling).
const SLIVER_CUTS: [f32; 14] = [
    0.0, 0.25, 0.26, 0.5, 0.75, 0.76, 0.995, 1.005, 1.25, 1.26, 1.5, 1.75, 1.76, 2.0,
];

/// A closed 2 m cube whose six walls are each cut into a 13 x 13 grid of faces at
/// [`SLIVER_CUTS`] (0.25 m squares, 1 cm x 0.25 m slivers, 1 cm squares), meshed one patch per
/// face: the ceiling's central 1 cm square is the only light (E = 1e4 W/m², 1 W, 1e-4 m²);
/// coloured walls as in [`tiny_light_room`]. The room is convex, so the reference solver is
/// exact to its quadrature tolerance.
fn slivers_room() -> (Scene, Subdivision) {
    let s = 2.0f32;
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    let cuts: &[f32] = &SLIVER_CUTS;
    let walls: [Wall; 6] = [
        (Vec3::ZERO, x, cuts, z, cuts, y, 0, false), // floor
        (s * y, x, cuts, z, cuts, -y, 3, true),      // ceiling
        (Vec3::ZERO, z, cuts, y, cuts, x, 1, false), // x = 0
        (s * x, z, cuts, y, cuts, -x, 2, false),     // x = s, the accent wall
        (Vec3::ZERO, x, cuts, y, cuts, z, 1, false), // z = 0
        (s * z, x, cuts, y, cuts, -z, 1, false),     // z = s
    ];
    (cut_walls(&walls), Subdivision::None)
}

/// A wall of [`cut_walls`]: origin, first axis (unit) and its cuts (m), second axis and its
/// cuts, the normal it faces, its material, and whether it is the ceiling (which holds the
/// light).
type Wall<'a> = (Vec3, Vec3, &'a [f32], Vec3, &'a [f32], Vec3, u32, bool);

/// The closed room of the slivers cases: each wall cut into a face per cell of its cuts, the
/// ceiling's cell at index ([`SLIVER_CUTS`]`.len() / 2 - 1`) along both axes the only light
/// (E = 1e4 W/m²), coloured walls as in [`tiny_light_room`].
fn cut_walls(walls: &[Wall]) -> Scene {
    let centre = SLIVER_CUTS.len() / 2 - 1;
    let mut positions = Vec::new();
    let mut faces = Vec::new();
    for &(p, u, us, v, vs, normal, material, ceiling) in walls {
        for i in 0..us.len() - 1 {
            for k in 0..vs.len() - 1 {
                let mut ring = [
                    p + us[i] * u + vs[k] * v,
                    p + us[i + 1] * u + vs[k] * v,
                    p + us[i + 1] * u + vs[k + 1] * v,
                    p + us[i] * u + vs[k + 1] * v,
                ];
                if u.cross(v).dot(normal) < 0.0 {
                    ring.reverse();
                }
                let base = positions.len() as u32;
                positions.extend(ring);
                let light = ceiling && i == centre && k == centre;
                let source = faces.len() as u32;
                faces.push(Face {
                    vertices: (base..base + 4).collect(),
                    material: if light { 4 } else { material },
                    source,
                });
            }
        }
    }
    let materials = vec![
        material("floor", Vec3::new(0.45, 0.35, 0.25), 0.0),
        material("wall", Vec3::new(0.7, 0.7, 0.68), 0.0),
        material("accent", Vec3::new(0.3, 0.5, 0.6), 0.0),
        material("ceiling", Vec3::splat(0.8), 0.0),
        material("light", Vec3::ZERO, 1e4),
    ];
    Scene::new(positions, faces, materials)
        .expect("the slivers' room is a valid scene")
        .0
}

/// A closed 2 x 2 x 8 m corridor (x, y up, z) whose walls are cut at [`SLIVER_CUTS`] across
/// and at the same cuts repeated every 2 m along, meshed one patch per face; the only light is
/// the 1 cm square at the ceiling's centre over `z` in `[0, 2]` (E = 1e4 W/m², 1 W); coloured
/// walls as in [`tiny_light_room`]. Convex, so the reference solver is exact to its
/// quadrature tolerance.
fn slivers_corridor() -> (Scene, Subdivision) {
    let (s, tiles) = (2.0f32, 4);
    let across: Vec<f32> = SLIVER_CUTS.to_vec();
    let mut along = vec![0.0f32];
    for t in 0..tiles {
        along.extend(SLIVER_CUTS[1..].iter().map(|c| c + s * t as f32));
    }
    let length = s * tiles as f32;
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    let walls: [Wall; 6] = [
        (Vec3::ZERO, x, &across, z, &along, y, 0, false), // floor
        (s * y, x, &across, z, &along, -y, 3, true),      // ceiling
        (Vec3::ZERO, z, &along, y, &across, x, 1, false), // x = 0
        (s * x, z, &along, y, &across, -x, 2, false),     // x = s, the accent wall
        (Vec3::ZERO, x, &across, y, &across, z, 1, false), // z = 0
        (length * z, x, &across, y, &across, -z, 1, false), // z = length
    ];
    (cut_walls(&walls), Subdivision::None)
}

/// A closed 2 m cube lit by a 0.5 × 0.5 ceiling light whose floor (two triangles) takes its
/// reflectance from an 8 × 8 checker texture (`u = x / 2`, `v = z / 2`): patches of the floor
/// differ in colour as the texture says, so every estimator's variance is checked on a scene
/// whose reflectance varies within a face.
fn textured_room() -> (Scene, Subdivision) {
    let s = 2.0f32;
    let l = 0.5f32;
    let mut positions = Vec::new();
    let mut faces = Vec::new();
    let mut polygon = |ring: Vec<Vec3>, normal: Vec3, material: u32| {
        let mut ring = ring;
        if (ring[1] - ring[0]).cross(ring[2] - ring[0]).dot(normal) < 0.0 {
            ring.reverse();
        }
        let base = positions.len() as u32;
        let n = ring.len() as u32;
        positions.extend(ring);
        let source = faces.len() as u32;
        faces.push(Face {
            vertices: (base..base + n).collect(),
            material,
            source,
        });
    };
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    let floor = [Vec3::ZERO, s * x, s * x + s * z, s * z];
    polygon(vec![floor[0], floor[1], floor[2]], y, 0); // faces 0 and 1: the textured floor
    polygon(vec![floor[0], floor[2], floor[3]], y, 0);
    polygon(vec![Vec3::ZERO, s * z, s * z + s * y, s * y], x, 1);
    polygon(
        vec![s * x, s * x + s * z, s * x + s * z + s * y, s * x + s * y],
        -x,
        1,
    );
    polygon(vec![Vec3::ZERO, s * x, s * x + s * y, s * y], z, 1);
    polygon(
        vec![s * z, s * z + s * x, s * z + s * x + s * y, s * z + s * y],
        -z,
        1,
    );
    let cs = [0.0, 0.5 * (s - l), 0.5 * (s + l), s];
    for i in 0..3 {
        for k in 0..3 {
            let (x0, x1, z0, z1) = (cs[i], cs[i + 1], cs[k], cs[k + 1]);
            let ring = vec![
                Vec3::new(x0, s, z0),
                Vec3::new(x1, s, z0),
                Vec3::new(x1, s, z1),
                Vec3::new(x0, s, z1),
            ];
            polygon(ring, -y, if i == 1 && k == 1 { 3 } else { 2 });
        }
    }
    let materials = vec![
        material("floor", Vec3::splat(0.9), 0.0),
        material("wall", Vec3::splat(0.6), 0.0),
        material("ceiling", Vec3::splat(0.7), 0.0),
        material("light", Vec3::ZERO, 50.0),
    ];
    let (scene, _) = Scene::new(positions.clone(), faces, materials).expect("a valid scene");
    let checker: Vec<Vec3> = (0..64)
        .map(|i| {
            if (i % 8 + i / 8) % 2 == 0 {
                Vec3::new(0.9, 0.5, 0.1)
            } else {
                Vec3::new(0.1, 0.3, 0.8)
            }
        })
        .collect();
    let texture = mcrad_scene_io::Texture::new(8, 8, checker, [mcrad_scene_io::Wrap::Repeat; 2])
        .expect("an 8 x 8 texture");
    let mapping = |t: [usize; 3]| {
        let corners = t.map(|i| positions[i]);
        Some(mcrad_scene_io::FaceMapping {
            corners,
            uv: corners.map(|p| glam::Vec2::new(p.x, p.z) / s),
            emissive_uv: corners.map(|p| glam::Vec2::new(p.x, p.z) / s),
            colors: [Vec3::ONE; 3],
            base: Some(0),
            emissive: None,
            alpha: None,
        })
    };
    let textures = mcrad_scene_io::SceneTextures {
        textures: vec![std::sync::Arc::new(texture)],
        faces: vec![mapping([0, 1, 2]), mapping([3, 4, 5])],
    };
    (scene.with_textures(textures), Subdivision::MaxEdge(0.15))
}

/// The calibration cases lit by lights without a surface (issue 34, item 4): a point light, a
/// spot light, and a sun with a uniform sky through a window. No face emits; the lights'
/// direct-light pass ([`Scene::lights`], [`Scene::sky`]) makes the first emission, so these
/// cases check its variance and how each method carries it on. Exact: the reference solver with
/// the lights' direct light computed deterministically (closed forms on wholly lit patches,
/// quadrature elsewhere and for the sky).
pub const LIT_CASES: [Case; 5] = [
    Case {
        name: "point-faces",
        what: "closed 4 x 2.5 x 3 room (coloured walls), no emitting face, an isotropic point \
               light of (40, 36, 32) W/sr at (1.3, 2.0, 1.1); one patch per face (6 patches); \
               exact: the reference solver (the light's direct light in closed form)",
        build: || (point_room(), Subdivision::None),
        exact: Exact::Reference,
        rays_factor: 1,
        rho: None,
        grain: Grain::Patches,
    },
    Case {
        name: "point",
        what: "the point-lit room of `point-faces`, patches of at most 0.25 (944); exact: the \
               reference solver",
        build: || (point_room(), Subdivision::MaxEdge(0.25)),
        exact: Exact::Reference,
        rays_factor: 2,
        rho: None,
        grain: Grain::Patches,
    },
    Case {
        name: "spot",
        what: "the room of `point-faces` lit by a spot light instead, (200, 190, 170) W/sr on \
               its axis, at (2.6, 2.3, 1.2) shining down and tilted towards x = 0, cones of 20° \
               and 35°; patches of at most 0.25 (944); exact: the reference solver (the cone by \
               quadrature)",
        build: || (spot_room(), Subdivision::MaxEdge(0.25)),
        exact: Exact::Reference,
        rays_factor: 2,
        rho: None,
        grain: Grain::Patches,
    },
    Case {
        name: "window-faces",
        what: "the 4 x 2.5 x 3 room with a 1.2 x 1 m window in its x = 4 wall (sill at 0.8 m), \
               a sun of 300 W/m² (direction towards it (0.7, 0.6, 0.3), 0.53°) lighting a patch \
               of the floor through it and a uniform sky of (20, 25, 35) W/(m² sr); one patch per \
               face (9 patches); exact: the reference solver (the sun by quadrature where a \
               patch is partly lit, the sky through the window by quadrature)",
        build: || (window_room(), Subdivision::None),
        exact: Exact::Reference,
        rays_factor: 1,
        rho: None,
        grain: Grain::Patches,
    },
    Case {
        name: "window",
        what: "the sun- and sky-lit room of `window-faces`, patches of at most 0.25 (940); \
               exact: the reference solver; run only when `--cases` names it (its reference \
               takes 40-125 s)",
        build: || (window_room(), Subdivision::MaxEdge(0.25)),
        exact: Exact::Reference,
        rays_factor: 2,
        rho: None,
        grain: Grain::Patches,
    },
];

/// Every case: [`CASES`], then [`LIT_CASES`].
fn all_cases() -> impl Iterator<Item = &'static Case> {
    CASES.iter().chain(LIT_CASES.iter())
}

/// Cases run only when `--cases` names them: the subdivided window room, whose reference
/// integrates the sky through the window on each of its 940 patches (40-125 s on 2 cores).
const NAMED_ONLY: [&str; 1] = ["window"];

/// Whether `scene` has lights without a surface or a sky (a case of [`LIT_CASES`]).
fn is_lit(scene: &Scene) -> bool {
    !scene.lights().is_empty() || scene.sky().is_some()
}

/// The rooms of [`LIT_CASES`]: a 4 (x) by 2.5 (y, up) by 3 (z) box, faces inward, no emitting
/// face, coloured walls as in [`tiny_light_room`]; with `window`, the x = 4 wall is cut around a
/// 1.2 (z, from 0.9) by 1 (y, from 0.8) m opening, so light leaves through it and a sun and the
/// sky come in. The faces lie on the box, so the room is convex with or without the window.
fn lit_box(
    window: bool,
    lights: Vec<mcrad_scene_io::Light>,
    sky: Option<mcrad_scene_io::Sky>,
) -> Scene {
    let (w, h, d) = (4.0f32, 2.5f32, 3.0f32);
    let mut r = Rects::default();
    let mut rect = |p, u, v, normal, material| r.add(p, u, v, normal, material);
    let (x, y, z) = (Vec3::X, Vec3::Y, Vec3::Z);
    rect(Vec3::ZERO, w * x, d * z, y, 0); // floor
    rect(h * y, w * x, d * z, -y, 3); // ceiling
    rect(Vec3::ZERO, d * z, h * y, x, 1); // x = 0
    rect(Vec3::ZERO, w * x, h * y, z, 1); // z = 0
    rect(d * z, w * x, h * y, -z, 1); // z = d
    if window {
        // x = w, the accent wall, around the opening [z0, z1] x [y0, y1]
        let (z0, z1, y0, y1) = (0.9f32, 2.1f32, 0.8f32, 1.8f32);
        let o = w * x;
        rect(o, d * z, y0 * y, -x, 2); // below
        rect(o + y1 * y, d * z, (h - y1) * y, -x, 2); // above
        rect(o + y0 * y, z0 * z, (y1 - y0) * y, -x, 2); // beside, z < z0
        rect(o + y0 * y + z1 * z, (d - z1) * z, (y1 - y0) * y, -x, 2); // beside, z > z1
    } else {
        rect(w * x, d * z, h * y, -x, 2); // x = w, the accent wall
    }
    let materials = vec![
        material("floor", Vec3::new(0.45, 0.35, 0.25), 0.0),
        material("wall", Vec3::new(0.7, 0.7, 0.68), 0.0),
        material("accent", Vec3::new(0.3, 0.5, 0.6), 0.0),
        material("ceiling", Vec3::splat(0.8), 0.0),
    ];
    Scene::new_lit_sky(r.positions, r.faces, materials, lights, sky)
        .expect("the lit room is a valid scene")
        .0
}

/// The closed room of [`lit_box`] lit by one isotropic point light of (40, 36, 32) W/sr at
/// (1.3, 2.0, 1.1), off every symmetry plane.
fn point_room() -> Scene {
    let light = mcrad_scene_io::Light::Point(mcrad_scene_io::PointLight {
        position: Vec3::new(1.3, 2.0, 1.1),
        intensity: DVec3::new(40.0, 36.0, 32.0),
        range: None,
    });
    lit_box(false, vec![light], None)
}

/// The closed room of [`lit_box`] lit by one spot light of (200, 190, 170) W/sr on its axis at
/// (2.6, 2.3, 1.2), shining down and tilted towards x = 0, with cones of 20° and 35°: its pool
/// of light falls on the floor and climbs the x = 0 wall.
fn spot_room() -> Scene {
    let light = mcrad_scene_io::Light::Spot(mcrad_scene_io::SpotLight {
        point: mcrad_scene_io::PointLight {
            position: Vec3::new(2.6, 2.3, 1.2),
            intensity: DVec3::new(200.0, 190.0, 170.0),
            range: None,
        },
        direction: Vec3::new(-0.6, -1.0, 0.2).normalize(),
        inner: 20f64.to_radians(),
        outer: 35f64.to_radians(),
    });
    lit_box(false, vec![light], None)
}

/// The room of [`lit_box`] with its window, lit through it by a sun of 300 W/m² (direction
/// towards it (0.7, 0.6, 0.3), 0.53°), whose patch of light falls on the floor, and a uniform
/// sky of (20, 25, 35) W/(m² sr).
fn window_room() -> Scene {
    let sun = mcrad_scene_io::Light::Sun(mcrad_scene_io::Sun {
        direction: Vec3::new(0.7, 0.6, 0.3).normalize(),
        irradiance: DVec3::splat(300.0),
        diameter: mcrad_scene_io::DEFAULT_SUN_DIAMETER,
    });
    let sky = mcrad_scene_io::Sky::Uniform(DVec3::new(20.0, 25.0, 35.0));
    lit_box(true, vec![sun], Some(sky))
}

/// The run's settings.
pub struct Options {
    /// Seeds `0..seeds` per (case, method).
    pub seeds: u64,
    /// Rays asked of every run.
    pub rays: u64,
    /// Cases run.
    pub cases: Vec<&'static Case>,
    /// Methods run.
    pub methods: Vec<Method>,
    /// Wall-clock limit of one run (seconds).
    pub limit: f64,
    /// The Markdown report's path.
    pub out: PathBuf,
    /// How the runs draw their rays (`--sampler random|qmc`).
    pub sampler: mcrad_mc_radiosity::Sampler,
    /// The reference solver's form-factor tolerance (`--reference-tolerance`), relative to a
    /// row's sum; a power bias below it passes whatever the standard error.
    pub reference_tolerance: f64,
    /// Where to write per-patch figures, one CSV per (case, method) ([`per_patch_csv`];
    /// `--per-patch DIR`), if anywhere.
    pub per_patch: Option<PathBuf>,
}

/// The arguments of `cargo xtask calibrate`.
#[derive(Debug, Clone, clap::Args)]
pub struct CalibrateArgs {
    /// Seeds 0..K per case and method (at least 2)
    #[arg(long, value_name = "K", default_value_t = DEFAULT_SEEDS)]
    pub seeds: u64,
    /// Rays asked of every run (e.g. 2e5)
    #[arg(long, value_name = "N", default_value_t = DEFAULT_RAYS, value_parser = crate::parse_count)]
    pub rays: u64,
    /// Cases, comma-separated [default: all]
    #[arg(long, value_name = "a,b", value_delimiter = ',')]
    pub cases: Vec<String>,
    /// Monte Carlo methods, comma-separated [default: all of them]
    #[arg(long, value_name = "m,n", value_delimiter = ',')]
    pub methods: Vec<Method>,
    /// Wall-clock limit of one run (seconds)
    #[arg(long, value_name = "S", default_value_t = DEFAULT_LIMIT)]
    pub limit: f64,
    /// The Markdown report, relative to the workspace
    #[arg(long, value_name = "FILE", default_value = "docs/calibration.md")]
    pub out: PathBuf,
    /// How the runs draw their rays [default: the library's]
    #[arg(long, value_name = "random|qmc")]
    pub sampler: Option<mcrad_mc_radiosity::Sampler>,
    /// The reference solver's form-factor tolerance, relative to a row's sum: a power bias
    /// below it passes whatever the standard error (tighter to judge biases of 1e-5)
    #[arg(long, value_name = "T", default_value_t = target::POWER_TOLERANCE)]
    pub reference_tolerance: f64,
    /// A directory (relative to the workspace) to write per-patch figures to, one CSV per
    /// case and method: which patches carry the z²
    #[arg(long, value_name = "DIR")]
    pub per_patch: Option<PathBuf>,
}

impl Options {
    /// The settings `args` ask for (the arguments after `calibrate`).
    pub fn parse(root: &Path, args: &CalibrateArgs) -> Result<Options> {
        let cases = if args.cases.is_empty() {
            all_cases()
                .filter(|c| !NAMED_ONLY.contains(&c.name))
                .collect()
        } else {
            args.cases
                .iter()
                .map(|n| {
                    all_cases().find(|c| c.name == n).with_context(|| {
                        let names: Vec<_> = all_cases().map(|c| c.name).collect();
                        format!("unknown case '{n}' (the cases: {})", names.join(", "))
                    })
                })
                .collect::<Result<_>>()?
        };
        let methods = if args.methods.is_empty() {
            Method::monte_carlo().collect()
        } else {
            args.methods.clone()
        };
        if let Some(m) = methods.iter().find(|m| **m == Method::Reference) {
            bail!("{m} is not a Monte Carlo method");
        }
        let o = Options {
            seeds: args.seeds,
            rays: args.rays,
            cases,
            methods,
            limit: args.limit,
            out: root.join(&args.out),
            sampler: args.sampler.unwrap_or_default(),
            reference_tolerance: args.reference_tolerance,
            per_patch: args.per_patch.as_ref().map(|d| root.join(d)),
        };
        if o.seeds < 2 || o.rays == 0 || o.limit.is_nan() || o.limit <= 0.0 {
            bail!("calibrate needs --seeds >= 2, --rays >= 1 and --limit > 0");
        }
        Ok(o)
    }
}

/// One complete run's answer.
#[derive(Debug, Clone)]
pub struct RunResult {
    /// `B` per patch (W/m²).
    pub radiosity: Vec<DVec3>,
    /// The reported variance of `B` per patch ((W/m²)²), if the method gave one.
    pub variance: Option<Vec<DVec3>>,
    /// Rays the run cast.
    pub rays: u64,
    /// It stopped because it converged, before spending its budget.
    pub converged: bool,
}

/// How one run ended.
enum Outcome {
    /// It finished (budget spent or converged), with the lights' pass's direct irradiance per
    /// patch (W/m², a lit case's; `None` otherwise).
    Done(RunResult, StopReason, Option<Vec<DVec3>>),
    /// The observer stopped it at the time limit.
    Stopped,
    /// It returned an error.
    Failed(String),
    /// It panicked.
    Panicked(String),
}

/// What a run solves ([`Grain`]).
#[derive(Clone, Copy)]
enum Target<'a> {
    /// This mesh, the answer per patch.
    Mesh(&'a Mesh),
    /// A case of [`LIT_CASES`]: this scene meshed by this subdivision, through the solve from
    /// its scene (which hands its lights and sky to the method), the answer per patch.
    Lit(&'a Scene, Subdivision),
    /// This scene meshed on the adaptive plan, the answer per input face.
    AdaptiveFaces(&'a Scene),
}

/// `radiosity` and `variance` per patch of `mesh` as per-face figures (`--per-face`: the
/// area-weighted mean of a face's patches, its variance `k_f sum a_i² V_i` with the factors
/// `k` of the correlation between them), in face order: `(B, variance, area)` per face.
fn per_face(
    mesh: &Mesh,
    radiosity: &[DVec3],
    variance: Option<&[DVec3]>,
    k: Option<&[DVec3]>,
) -> (Vec<DVec3>, Option<Vec<DVec3>>, Vec<f64>) {
    let numbers: Vec<u32> = (0..mesh.patches().len() as u32).collect();
    let rows = mcrad_export::per_face(
        mcrad_export::patch_rows(mesh, &numbers, radiosity, variance),
        k,
    );
    (
        rows.iter().map(|r| r.radiosity).collect(),
        rows.iter().map(|r| r.variance).collect(),
        rows.iter().map(|r| r.area).collect(),
    )
}

/// Runs `method` once through the library's solve of `target`, panics caught, stopped at its
/// first step past `limit` seconds.
fn run_once(method: Method, target: Target, config: &ScheduleConfig, limit: f64) -> (Outcome, f64) {
    let start = Instant::now();
    let result = catch_unwind(AssertUnwindSafe(|| {
        let mut observer = |_: &mcrad_solve::Progress| {
            if start.elapsed().as_secs_f64() > limit {
                ControlFlow::Break(())
            } else {
                ControlFlow::Continue(())
            }
        };
        let answer = match target {
            Target::Mesh(mesh) => crate::solve_fixed(method, mesh, config, &mut observer),
            Target::Lit(scene, subdivision) => {
                solve_lit(method, scene, subdivision, config, &mut observer)
            }
            Target::AdaptiveFaces(scene) => crate::solve_input(
                method,
                mcrad_solve::Input::Scene(scene),
                mcrad_solve::MeshPlan::default(),
                config,
                &mut observer,
            ),
        };
        answer.map(|a| {
            let (e, stop) = (&a.estimate, a.stats.stop);
            let (radiosity, variance) = match target {
                Target::Mesh(_) | Target::Lit(..) => {
                    (e.radiosity().to_vec(), e.variance().map(<[DVec3]>::to_vec))
                }
                Target::AdaptiveFaces(_) => {
                    let k = a.face_correlation.as_deref();
                    let (b, v, _) = per_face(&a.mesh, e.radiosity(), e.variance(), k);
                    (b, v)
                }
            };
            let direct = match target {
                Target::Lit(..) => a.direct.clone().map(mcrad_solve::PerPatch::into_vec),
                _ => None,
            };
            (radiosity, variance, a.stats.rays, stop, direct)
        })
    }));
    let secs = start.elapsed().as_secs_f64();
    let outcome = match result {
        Ok(Ok((_, _, _, StopReason::Stopped, _))) => Outcome::Stopped,
        Ok(Ok((radiosity, variance, rays, stop, direct))) => Outcome::Done(
            RunResult {
                radiosity,
                variance,
                rays,
                converged: stop == StopReason::Converged,
            },
            stop,
            direct,
        ),
        Ok(Err(e)) => Outcome::Failed(e.to_string()),
        Err(payload) => Outcome::Panicked(
            payload
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "(no message)".into()),
        ),
    };
    (outcome, secs)
}

/// [`crate::solve_fixed`] for a lit case: the library's solve from `scene` (its lights and sky
/// included, as `mcrad solve` runs a scene) meshed as `subdivision` says, which is the mesh the
/// case's statistics and reference are computed on (the same build of the same scene).
fn solve_lit(
    method: Method,
    scene: &Scene,
    subdivision: Subdivision,
    config: &ScheduleConfig,
    observer: &mut mcrad_solve::Observer,
) -> Result<mcrad_solve::Answer, mcrad_solve::Error> {
    let mesh = match subdivision {
        Subdivision::None => mcrad_solve::MeshPlan::PerFace,
        Subdivision::MaxEdge(l) => mcrad_solve::MeshPlan::Uniform { max_edge: Some(l) },
    };
    crate::solve_input(
        method,
        mcrad_solve::Input::Scene(scene),
        mesh,
        config,
        observer,
    )
}

/// The statistics of K complete runs of one method on one case.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Stats {
    /// Mean of `z² = (B - exact)² / var` over runs, patches and channels with `var > 0`.
    pub z2: Option<f64>,
    /// The kurtosis of `z` over the same entries, `mean(z⁴) / mean(z²)²`: 3 for normal errors,
    /// about `1/p` for errors made of rare events of probability `p` (a small light that most
    /// runs' rays miss).
    pub z_kurtosis: Option<f64>,
    /// (run, patch, channel) entries with a reported variance of exactly 0 on a `B` that is not
    /// exact (relative error above 1e-9; every one when the exact answer is unknown), left out
    /// of `z2`. A variance of 0 on an exact `B` (a light that reflects nothing) is not counted.
    pub zero_var: usize,
    /// (run, patch, channel) entries of runs that reported no variance.
    pub no_var: usize,
    /// (run, patch, channel) entries with a reported variance of exactly 0 on an exact `B`
    /// (`|B - exact| <= 1e-9 exact`): a true claim, left out of `z2` and of the misses.
    pub exact: usize,
    /// Runs that converged before spending their budget with every entry exact (variance 0 on
    /// an exact `B`): their budget use is shown apart and is no miss.
    pub exact_early: usize,
    /// Pooled spread / reported: the sum over patches and channels of the between-seed sample
    /// variance of `B` divided by the sum of the mean reported variance. 1 when calibrated.
    pub spread_pooled: Option<f64>,
    /// The median over patches and channels of (between-seed sample variance / mean reported
    /// variance), divided by the median of `chi²(K-1) / (K-1)` (what the median of the ratio
    /// is when calibrated and normal): 1 when calibrated.
    pub spread_median: Option<f64>,
    /// `(P - P_exact) / P_exact` of the power `P = sum_i A_i (B_r + B_g + B_b)` of the mean of
    /// the runs.
    pub power_bias: Option<f64>,
    /// The standard error of `power_bias`: the spread of the runs' powers / sqrt(K), relative
    /// to `P_exact`.
    pub power_se: Option<f64>,
    /// Rays used / rays asked: the smallest and the largest over the runs, the
    /// `exact_early` ones left out (`None` if every run is one).
    pub budget: Option<(f64, f64)>,
    /// The same over the `exact_early` runs.
    pub budget_exact_early: Option<(f64, f64)>,
}

/// The statistics of `runs` (each one complete run) against `exact` (per patch, W/m²) when
/// known; `areas` per patch; `asked` the rays asked of each run.
pub fn statistics(runs: &[RunResult], exact: Option<&[DVec3]>, areas: &[f64], asked: u64) -> Stats {
    let mut s = Stats::default();
    if runs.is_empty() {
        return s;
    }
    let k = runs.len() as f64;
    let n = areas.len();
    // z²
    let mut exact_run = vec![false; runs.len()];
    if let Some(exact) = exact {
        let (mut sum, mut sum4, mut count) = (0.0, 0.0, 0usize);
        for (r, exact_run) in runs.iter().zip(&mut exact_run) {
            let Some(v) = &r.variance else {
                s.no_var += 3 * n;
                continue;
            };
            let mut all_exact = true;
            for i in 0..n {
                for c in 0..3 {
                    let error = r.radiosity[i][c] - exact[i][c];
                    if v[i][c] > 0.0 {
                        let z2 = error.powi(2) / v[i][c];
                        sum += z2;
                        sum4 += z2 * z2;
                        count += 1;
                        all_exact = false;
                    } else if error.abs() > 1e-9 * exact[i][c].abs() {
                        // a variance of 0 on an exact answer (an emitter that reflects
                        // nothing, a furnace where every ray sees the same value) is true;
                        // on any other it claims an exactness it lacks
                        s.zero_var += 1;
                        all_exact = false;
                    } else {
                        s.exact += 1;
                    }
                }
            }
            *exact_run = all_exact && r.converged;
        }
        s.exact_early = exact_run.iter().filter(|&&e| e).count();
        s.z2 = (count > 0).then(|| sum / count as f64);
        s.z_kurtosis =
            s.z2.filter(|z2| *z2 > 0.0)
                .map(|z2| sum4 / count as f64 / (z2 * z2));
    } else {
        s.no_var = runs.iter().filter(|r| r.variance.is_none()).count() * 3 * n;
        s.zero_var = runs
            .iter()
            .filter_map(|r| r.variance.as_ref())
            .map(|v| {
                v.iter()
                    .map(|x| x.to_array().iter().filter(|&&y| y <= 0.0).count())
                    .sum::<usize>()
            })
            .sum();
    }
    // spread / reported
    let with_var: Vec<&Vec<DVec3>> = runs.iter().filter_map(|r| r.variance.as_ref()).collect();
    if runs.len() >= 2 && with_var.len() == runs.len() {
        let (mut spread_sum, mut reported_sum, mut ratios) = (0.0, 0.0, Vec::new());
        for i in 0..n {
            for c in 0..3 {
                let mean = runs.iter().map(|r| r.radiosity[i][c]).sum::<f64>() / k;
                let spread = runs
                    .iter()
                    .map(|r| (r.radiosity[i][c] - mean).powi(2))
                    .sum::<f64>()
                    / (k - 1.0);
                let reported = with_var.iter().map(|v| v[i][c]).sum::<f64>() / k;
                spread_sum += spread;
                reported_sum += reported;
                if reported > 0.0 {
                    ratios.push(spread / reported);
                }
            }
        }
        s.spread_pooled = (reported_sum > 0.0).then(|| spread_sum / reported_sum);
        if !ratios.is_empty() {
            ratios.sort_by(f64::total_cmp);
            let m = ratios.len();
            let median = if m % 2 == 1 {
                ratios[m / 2]
            } else {
                0.5 * (ratios[m / 2 - 1] + ratios[m / 2])
            };
            let dof = k - 1.0;
            let chi2_median = ChiSquared::new(dof).expect("k >= 2").inverse_cdf(0.5) / dof;
            s.spread_median = Some(median / chi2_median);
        }
    }
    // power of the mean
    if let Some(exact) = exact {
        let power = |b: &[DVec3]| -> f64 {
            b.iter()
                .zip(areas)
                .map(|(b, a)| a * (b.x + b.y + b.z))
                .sum()
        };
        let exact_power = power(exact);
        let powers: Vec<f64> = runs.iter().map(|r| power(&r.radiosity)).collect();
        let mean = powers.iter().sum::<f64>() / k;
        s.power_bias = Some((mean - exact_power) / exact_power);
        if runs.len() >= 2 {
            let var = powers.iter().map(|p| (p - mean).powi(2)).sum::<f64>() / (k - 1.0);
            s.power_se = Some((var / k).sqrt() / exact_power.abs());
        }
    }
    let used = |early: bool| -> Option<(f64, f64)> {
        let used: Vec<f64> = runs
            .iter()
            .zip(&exact_run)
            .filter(|(_, e)| **e == early)
            .map(|(r, _)| r.rays as f64 / asked as f64)
            .collect();
        (!used.is_empty()).then(|| {
            (
                used.iter().copied().fold(f64::INFINITY, f64::min),
                used.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            )
        })
    };
    s.budget = used(false);
    s.budget_exact_early = used(true);
    s
}

/// One row of the table: a (case, method) pair.
struct Row {
    case: &'static Case,
    method: Method,
    stats: Stats,
    /// Complete runs.
    done: usize,
    /// Seeds asked.
    seeds: u64,
    /// Mean wall-clock seconds of a run (over every run that ended).
    seconds: f64,
    /// What went wrong: errors, panics, stops at the limit, runs that converged early.
    notes: Vec<String>,
}

/// Runs the suite and writes the report.
pub fn run(root: &Path, args: &CalibrateArgs) -> Result<()> {
    let o = Options::parse(root, args)?;
    let start = Instant::now();
    let rows = measure(&o)?;
    let table = table(&rows, o.reference_tolerance) + &far_table(&rows);
    print!("{table}");
    let mut doc = document(&o, &table);
    let _ = write!(
        doc,
        "\nThe suite took {:.0} s of wall-clock time (the reference solution included).\n",
        start.elapsed().as_secs_f64()
    );
    std::fs::write(&o.out, doc).with_context(|| format!("could not write {}", o.out.display()))?;
    eprintln!("wrote {}", o.out.display());
    Ok(())
}

/// Runs every (case, method, seed) of `o`.
fn measure(o: &Options) -> Result<Vec<Row>> {
    // Panics are caught and reported in the table; the default hook would print each one.
    let hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let rows = measure_all(o);
    std::panic::set_hook(hook);
    rows
}

fn measure_all(o: &Options) -> Result<Vec<Row>> {
    let mut rows = Vec::new();
    for case in &o.cases {
        let (scene, subdivision) = (case.build)();
        let mesh = Mesh::build(&scene, subdivision)?;
        let bvh = mesh.caster()?;
        let mut areas: Vec<f64> = mesh.patches().iter().map(|p| p.area).collect();
        eprintln!("{}: {} patches", case.name, mesh.patches().len());
        // A lit case's runs go through the solve from the scene (its lights and sky); the
        // reference gets them too.
        let lit = is_lit(&scene).then_some((&scene, subdivision));
        let mut reference_config = ScheduleConfig {
            lights: scene.lights().to_vec(),
            sky: scene.sky().cloned(),
            ..Default::default()
        };
        reference_config.reference.tolerance = o.reference_tolerance;
        // the reference's direct irradiance of the lights per patch (a lit case's)
        let mut reference_direct: Option<Vec<DVec3>> = None;
        let mut exact: Option<Vec<DVec3>> = match case.exact {
            Exact::Furnace => Some(
                mesh.patches()
                    .iter()
                    .map(|p| p.emission.as_dvec3() / (DVec3::ONE - p.reflectance.as_dvec3()))
                    .collect(),
            ),
            Exact::Reference => {
                let start = Instant::now();
                let r = mcrad_mc_radiosity::run(
                    Method::Reference,
                    &mesh,
                    &bvh,
                    &reference_config,
                    &mut |_| ControlFlow::Continue(()),
                );
                eprintln!(
                    "  reference solution: {:.1} s",
                    start.elapsed().as_secs_f64()
                );
                match r {
                    Ok(s) => {
                        reference_direct = s.direct.clone();
                        Some(s.estimate.radiosity().to_vec())
                    }
                    Err(e) => {
                        eprintln!("warning: no reference for {}: {e}", case.name);
                        None
                    }
                }
            }
        };
        let target = match (case.grain, lit) {
            (Grain::Patches, Some((scene, subdivision))) => Target::Lit(scene, subdivision),
            (Grain::Patches, None) => Target::Mesh(&mesh),
            (Grain::AdaptiveFaces, _) => {
                exact = exact.map(|b| per_face(&mesh, &b, None, None).0);
                areas = per_face(&mesh, &vec![DVec3::ZERO; areas.len()], None, None).2;
                eprintln!("  judged per face: {} faces", areas.len());
                Target::AdaptiveFaces(&scene)
            }
        };
        for &method in &o.methods {
            let mut runs = Vec::new();
            let mut directs = Vec::new();
            let mut notes = Vec::new();
            let (mut seconds, mut ended) = (0.0, 0usize);
            let (mut converged, mut stopped) = (0usize, false);
            for seed in 0..o.seeds {
                let config = ScheduleConfig {
                    rays: o.rays * case.rays_factor,
                    seed,
                    sampler: o.sampler,
                    ..Default::default()
                };
                let (outcome, secs) = run_once(method, target, &config, o.limit);
                seconds += secs;
                ended += 1;
                match outcome {
                    Outcome::Done(r, stop, d) => {
                        converged += usize::from(stop == StopReason::Converged);
                        runs.push(r);
                        directs.push(d);
                    }
                    Outcome::Stopped => {
                        notes.push(format!(
                            "seed {seed} stopped at the {:.0} s limit ({secs:.1} s); \
                             later seeds skipped",
                            o.limit
                        ));
                        stopped = true;
                    }
                    Outcome::Failed(e) => notes.push(format!("seed {seed}: error: {e}")),
                    Outcome::Panicked(e) => notes.push(format!("seed {seed}: panic: {e}")),
                }
                if stopped {
                    break;
                }
            }
            if converged > 0 {
                notes.push(format!("converged early: {converged}"));
            }
            let stats = statistics(&runs, exact.as_deref(), &areas, o.rays * case.rays_factor);
            if let (Some(dir), Grain::Patches) = (&o.per_patch, case.grain) {
                let path = dir.join(format!("{}-{method}.csv", case.name));
                let csv = per_patch_csv(
                    &mesh,
                    &runs,
                    &directs,
                    exact.as_deref(),
                    reference_direct.as_deref(),
                );
                std::fs::write(&path, csv)
                    .with_context(|| format!("could not write {}", path.display()))?;
            }
            eprintln!(
                "  {method}: {}/{} runs, {:.2} s per run",
                runs.len(),
                o.seeds,
                seconds / ended as f64
            );
            rows.push(Row {
                case,
                method,
                stats,
                done: runs.len(),
                seeds: o.seeds,
                seconds: seconds / ended as f64,
                notes: dedup_notes(notes),
            });
        }
    }
    Ok(rows)
}

/// Per-patch figures of `runs` of one (case, method) on `mesh` as CSV, one row per patch, the
/// green channel's (W/m², (W/m²)²): `exact`; the runs' `mean`, their sample variance `spread`
/// and the mean `reported` variance; `z2` the mean of `z² = (B - exact)² / var` over the runs
/// and `z2_max` its largest, with that run's index `worst`; `bias_se`, `(mean - exact)` in
/// standard errors `sqrt(spread / K)`. For a lit case also the lights' pass's `rho H` (its mean
/// over the runs, `pass_mean`, and spread, `pass_spread`) and the reference's, `ref_direct`;
/// and `pass_worst`, the pass's `rho H` in the run `worst`. Which patches carry a case's mean
/// z², and whether it is the method's variance, a bias, or the reference.
fn per_patch_csv(
    mesh: &Mesh,
    runs: &[RunResult],
    directs: &[Option<Vec<DVec3>>],
    exact: Option<&[DVec3]>,
    reference_direct: Option<&[DVec3]>,
) -> String {
    let mut out = String::from(
        "patch,face,x,y,z,area,exact,mean,spread,reported,z2,z2_max,worst,bias_se,\
         pass_mean,pass_spread,pass_worst,ref_direct\n",
    );
    let k = runs.len() as f64;
    let c = 1;
    for (i, p) in mesh.patches().iter().enumerate() {
        let rho = f64::from(p.reflectance[c]);
        let values: Vec<f64> = runs.iter().map(|r| r.radiosity[i][c]).collect();
        let mean = values.iter().sum::<f64>() / k;
        let spread = values.iter().map(|b| (b - mean).powi(2)).sum::<f64>() / (k - 1.0).max(1.0);
        let reported = runs
            .iter()
            .filter_map(|r| r.variance.as_ref().map(|v| v[i][c]))
            .sum::<f64>()
            / k;
        let ex = exact.map_or(f64::NAN, |e| e[i][c]);
        let z2: Vec<f64> = runs
            .iter()
            .map(|r| {
                r.variance
                    .as_ref()
                    .map_or(f64::NAN, |v| (r.radiosity[i][c] - ex).powi(2) / v[i][c])
            })
            .collect();
        let (worst, z2_max) = z2
            .iter()
            .copied()
            .enumerate()
            .fold((0, f64::NEG_INFINITY), |a, b| if b.1 > a.1 { b } else { a });
        let pass: Vec<f64> = directs
            .iter()
            .map(|d| d.as_ref().map_or(f64::NAN, |d| rho * d[i][c]))
            .collect();
        let pass_mean = pass.iter().sum::<f64>() / k;
        let pass_spread =
            pass.iter().map(|h| (h - pass_mean).powi(2)).sum::<f64>() / (k - 1.0).max(1.0);
        let _ = writeln!(
            out,
            "{i},{},{:.4},{:.4},{:.4},{:.6},{ex:.6e},{mean:.6e},{spread:.4e},{reported:.4e},\
             {:.4},{z2_max:.4},{worst},{:.3},{pass_mean:.6e},{pass_spread:.4e},{:.6e},{:.6e}",
            p.face,
            p.centroid.x,
            p.centroid.y,
            p.centroid.z,
            p.area,
            z2.iter().sum::<f64>() / k,
            (mean - ex) / (spread / k).sqrt(),
            pass.get(worst).copied().unwrap_or(f64::NAN),
            reference_direct.map_or(f64::NAN, |d| rho * d[i][c]),
        );
    }
    out
}

/// Collapses repeated messages (the same error on every seed) into one with a count.
fn dedup_notes(notes: Vec<String>) -> Vec<String> {
    let mut out: Vec<(String, usize)> = Vec::new();
    for n in notes {
        // "seed 3: panic: x" and "seed 4: panic: x" are the same message
        let key = match n.split_once(": ") {
            Some((seed, rest)) if seed.starts_with("seed ") => rest.to_string(),
            _ => n,
        };
        match out.iter_mut().find(|(k, _)| *k == key) {
            Some((_, c)) => *c += 1,
            None => out.push((key, 1)),
        }
    }
    out.into_iter()
        .map(|(k, c)| if c > 1 { format!("{c} seeds: {k}") } else { k })
        .collect()
}

/// A ratio in standard errors: one decimal, or in powers of ten beyond 1e4 (a standard error
/// of rounding noise).
fn ratio(v: f64) -> String {
    if v.abs() < 1e4 {
        format!("{v:+.1}")
    } else {
        format!("{v:+.0e}")
    }
}

/// A value with `✗` when it misses `ok`.
fn cell(value: Option<f64>, fmt: impl Fn(f64) -> String, ok: impl Fn(f64) -> bool) -> String {
    match value {
        None => "–".into(),
        Some(v) if ok(v) => fmt(v),
        Some(v) => format!("{} ✗", fmt(v)),
    }
}

fn within((lo, hi): (f64, f64)) -> impl Fn(f64) -> bool {
    move |v| (lo..=hi).contains(&v)
}

/// The Markdown table of the rows.
fn table(rows: &[Row], tolerance: f64) -> String {
    let mut t = String::from(
        "| case | method | runs | mean z² | z kurtosis | var 0 / none | spread/reported pooled | \
         spread/reported median | power bias | ± SE | bias / SE | budget used | s/run | notes |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|\n",
    );
    for r in rows {
        let s = &r.stats;
        let high_rho = r.case.rho.is_some_and(|rho| rho >= 0.999);
        let bias_se = match (s.power_bias, s.power_se) {
            (Some(b), Some(se)) => Some(b / se.max(tolerance / target::POWER_SE)),
            _ => None,
        };
        let range = |(lo, hi): (f64, f64)| {
            if (hi - lo) < 0.005 {
                format!("{:.1}%", 100.0 * lo)
            } else {
                format!("{:.1}-{:.1}%", 100.0 * lo, 100.0 * hi)
            }
        };
        let mut budget = match s.budget {
            None => String::new(),
            Some((lo, hi)) if within(target::BUDGET)(lo) && within(target::BUDGET)(hi) => {
                range((lo, hi))
            }
            Some(b) => format!("{} ✗", range(b)),
        };
        if let Some(b) = s.budget_exact_early {
            if !budget.is_empty() {
                budget.push_str("; ");
            }
            let _ = write!(budget, "{} exact early", range(b));
        }
        if budget.is_empty() {
            budget.push('–');
        }
        // Every entry exact with variance 0: nothing to calibrate, and nothing wrong.
        let all_exact = s.z2.is_none() && s.exact > 0 && s.zero_var + s.no_var == 0;
        let calibrated = |value: Option<f64>| {
            if all_exact && value.is_none() {
                "exact".to_string()
            } else {
                cell(value, |v| format!("{v:.3}"), within(target::SPREAD))
            }
        };
        let median = match s.spread_median {
            Some(v) if !median_judged(s, r.seeds) => format!("{v:.3} (rare events)"),
            v => calibrated(v),
        };
        let zero = if s.zero_var + s.no_var == 0 {
            "0".to_string()
        } else {
            format!("{} / {} ✗", s.zero_var, s.no_var)
        };
        let _ = writeln!(
            t,
            "| {} | {} | {}/{}{} | {} | {} | {zero} | {} | {median} | {} | {} | {} | {budget} | {:.2} | {} |",
            r.case.name,
            r.method,
            r.done,
            r.seeds,
            if (r.done as u64) < r.seeds {
                " ✗"
            } else {
                ""
            },
            if all_exact {
                "exact".to_string()
            } else {
                cell(s.z2, |v| format!("{v:.3}"), within(target::Z2))
            },
            cell(s.z_kurtosis, |v| format!("{v:.1}"), |_| true),
            calibrated(s.spread_pooled),
            cell(
                s.power_bias,
                |v| format!("{:+.4}%", 100.0 * v),
                |v| !high_rho || v.abs() <= target::HIGH_RHO
            ),
            cell(s.power_se, |v| format!("{:.4}%", 100.0 * v), |_| true),
            cell(bias_se, ratio, |v| v.abs() <= target::POWER_SE),
            r.seconds,
            r.notes.join("; ").replace('|', "/"),
        );
    }
    t
}

/// The far furnace against the one at the origin, per method: the difference of their power
/// biases in combined standard errors (target: within 3).
fn far_table(rows: &[Row]) -> String {
    let mut t = String::from(
        "\n| method | power far − origin | in SE | mean z² origin / far | s/run origin / far |\n\
         |---|---:|---:|---:|---:|\n",
    );
    let mut any = false;
    for far in rows.iter().filter(|r| r.case.name == "furnace-far") {
        let Some(origin) = rows
            .iter()
            .find(|r| r.case.name == "furnace-0.5" && r.method == far.method)
        else {
            continue;
        };
        let (a, b) = (&origin.stats, &far.stats);
        let (Some(pa), Some(pb), Some(sa), Some(sb)) =
            (a.power_bias, b.power_bias, a.power_se, b.power_se)
        else {
            continue;
        };
        any = true;
        let se = (sa * sa + sb * sb).sqrt();
        let z = if pb == pa { 0.0 } else { (pb - pa) / se };
        let z2 = |v: Option<f64>| v.map_or("–".into(), |v| format!("{v:.3}"));
        let z2 = |s: &Stats| {
            if s.z2.is_none() && s.exact > 0 {
                "exact".to_string()
            } else {
                z2(s.z2)
            }
        };
        let _ = writeln!(
            t,
            "| {} | {:+.4}% | {} | {} / {} | {:.2} / {:.2} |",
            far.method,
            100.0 * (pb - pa),
            cell(Some(z), ratio, |v| v.abs() <= target::POWER_SE),
            z2(a),
            z2(b),
            origin.seconds,
            far.seconds
        );
    }
    if any { t } else { String::new() }
}

/// The report: what was run, what each column means, the targets, the table.
fn document(o: &Options, table: &str) -> String {
    let mut d = String::new();
    let _ = write!(
        d,
        "# Calibration: are the reported variances true and the answers unbiased?\n\n\
         Written by `cargo xtask calibrate` (xtask/src/calibrate.rs; issue 16, item 6). This run: \
         {} seeds (0..{}) per case and method, {} rays asked of every run, a run stopped at its \
         first step after {} s, rays drawn by the `{}` sampler. Rerun with `cargo xtask \
         calibrate [--seeds K] [--rays N] [--cases a,b] [--methods m,n] [--limit S] \
         [--sampler random|qmc] [--reference-tolerance T]`.\n\n",
        o.seeds,
        o.seeds,
        o.rays,
        o.limit,
        o.sampler.name()
    );
    d.push_str("## Cases\n\n| case | rays per run | what |\n|---|---:|---|\n");
    for c in &o.cases {
        let _ = writeln!(
            d,
            "| {} | {} | {} |",
            c.name,
            o.rays * c.rays_factor,
            c.what
        );
    }
    d.push_str(
        "\nEvery case is closed, so exactness is not a matter of escaping light. The furnaces' \
         subdivision is the default (diagonal / 20: 12 x 12 patches a face, 864 patches), but \
         for the `-faces` cases, one patch per face (issue 36, item 2); far from the origin every vertex is an integer, exact in `f32`, so the far furnace is the \
         same mesh as the one at the origin, moved. The room is convex (the light is part of \
         the ceiling), so the reference solver needs no visibility and its answer is exact to \
         its quadrature tolerance (`--reference-tolerance`, by default 1e-4 of a row's sum) \
         and residual (1e-9).\n\n",
    );
    if o.cases
        .iter()
        .any(|c| LIT_CASES.iter().any(|l| l.name == c.name))
    {
        d.push_str(
            "The lit cases (`point`, `spot`, `window`, issue 34) have no emitting face: a \
             point light, a spot light, or a sun and a uniform sky through a window light them, \
             and each run goes through the solve from the scene, as `mcrad solve` does, so the \
             lights' direct-light pass makes the first emission and its variance is part of \
             what is reported. The window room is open (light leaves through the window); its \
             faces still lie on a box, so it is convex. Their reference computes the lights' \
             direct light deterministically: a point light in closed form on wholly lit \
             patches, the spot's cone, a partly lit patch and the sky by quadrature (the sky's \
             error about 2.5e-3 of a window-lit patch's sky irradiance).\n\n",
        );
    }
    d.push_str(
        "## Columns\n\n\
         - **runs**: complete runs / seeds asked. A run that errs, panics, or is stopped at the \
         time limit is left out of the statistics and named in *notes*.\n\
         - **mean z²**: the mean over runs, patches and channels of `z² = (B - exact)² / var`, \
         with `var` the variance the run reported for that `B`. 1 when the reported variance is \
         the true mean squared error (a noisy variance estimate pushes it above 1, a bias too).\n\
         - **z kurtosis**: `mean(z⁴) / mean(z²)²` over the same entries: 3 for normal errors, \
         about `1/p` for errors made of rare events of probability `p` per run (a small light \
         that most rays miss: pure gathering in the tiny-light room).\n\
         - **var 0 / none**: (run, patch, channel) entries whose reported variance is exactly 0 \
         while `B` is not exact / entries of runs that reported no variance. They are left out \
         of mean z² and count as misses: a variance of 0 claims an exact answer. (The light of \
         the room reflects nothing: its `B = E` is exact and its variance 0 is true, so it is \
         not counted.) A (case, method) whose every entry is exact with variance 0 (`|B - \
         exact| <= 1e-9 exact`: gathering in a furnace, where every ray sees the same value) \
         shows *exact* in mean z² and both spread columns: there is nothing to calibrate.\n\
         - **notes**: errors, panics and stops at the time limit (per seed, repeated messages \
         counted), and how many runs converged before spending their budget (shooting: unshot \
         power below 1e-4 of the emitted; gathering: a round changed little).\n\
         - **spread/reported pooled**: over patches and channels, the sum of the sample variance \
         of `B` between the seeds divided by the sum of the mean reported variance. 1 when \
         calibrated; dominated by the patches with the largest variances.\n\
         - **spread/reported median**: the median over patches and channels of the same ratio \
         per patch, divided by the median of `chi²(K-1)/(K-1)` (0.90 for K = 8, 0.96 for K = 16), the median of \
         the ratio when calibrated and normal. Every patch counts once. Where the z kurtosis \
         exceeds K / ln 2 (rare events, `p < ln 2 / K`), the median patch saw no event in its K \
         runs: its spread lacks what its true variance includes, and the median is far below \
         1 however true the variance (a synthetic test, `rare_events_defeat_the_median_not_the_\
         pooled_ratio`, shows it: 0 for exact variances). It is then shown as *(rare events)* and \
         not judged; the pooled ratio, which sums every patch's events, and mean z² are the \
         checks.\n\
         - **power bias**: `(P - P_exact) / P_exact` for the total power `P = sum_i A_i (B_r + \
         B_g + B_b)` of the mean of the K runs.\n\
         - **± SE**: its standard error, the standard deviation of the runs' powers / sqrt(K), \
         relative to `P_exact`. **bias / SE**: their ratio, with the SE taken as at least \
         T / 3 (a bias below T of the power, the reference solver's own tolerance \
         `--reference-tolerance`, by default 1e-4, passes: shooting's power has no other \
         noise).\n\
         - **budget used**: rays cast / rays asked, smallest and largest over the runs. A run \
         that converged before spending its budget with every entry exact (variance 0) is shown \
         apart as *exact early* and is no miss: more rays could not improve it.\n\
         - **s/run**: mean wall-clock seconds of a run on this machine (all cores).\n\n\
         ## Targets (issue 16)\n\n\
         A cell marked ✗ misses its target: spread/reported (both columns; the median where \
         judged) in [0.67, 1.5]; \
         mean z² in [0.7, 1.5]; no variance 0 or missing; the power of the mean within 3 \
         standard errors of exact (bias / SE); at rho 0.999 the power within 1% of exact (power \
         bias); budgets used 95-105%; every seed complete. The issue asks for 16 seeds for the \
         power target, the default here. The far furnace must equal the one at the origin \
         within noise: the second table gives, per method, the difference of the two power biases \
         in combined standard errors (✗ beyond 3), their mean z² and their time per run.\n\n\
         ## Results\n\n",
    );
    d.push_str(table);
    d
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grey(x: f64) -> DVec3 {
        DVec3::splat(x)
    }

    /// Exact numbers: two runs of two patches, every quantity computed by hand.
    #[test]
    fn statistics_of_hand_computed_runs() {
        let exact = [grey(1.0), grey(2.0)];
        let areas = [1.0, 3.0];
        let runs = [
            RunResult {
                radiosity: vec![grey(1.5), grey(2.0)],
                variance: Some(vec![grey(0.25), grey(1.0)]),
                rays: 90,
                converged: false,
            },
            RunResult {
                radiosity: vec![grey(0.5), grey(3.0)],
                variance: Some(vec![grey(0.25), grey(0.0)]),
                rays: 110,
                converged: false,
            },
        ];
        let s = statistics(&runs, Some(&exact), &areas, 100);
        // z² per channel: run 0: 1, 0; run 1: 1, (var 0: left out) -> mean of 1, 0, 1 = 2/3
        assert!((s.z2.unwrap() - 2.0 / 3.0).abs() < 1e-12, "{s:?}");
        assert_eq!((s.zero_var, s.no_var), (3, 0));
        // spread: patch 0: mean 1, sample var 0.5; patch 1: mean 2.5, sample var 0.5.
        // reported means: 0.25 and 0.5. pooled: 3 (0.5 + 0.5) / 3 (0.25 + 0.5) = 4/3
        assert!((s.spread_pooled.unwrap() - 4.0 / 3.0).abs() < 1e-12);
        // median ratio of {2, 2, 2, 1, 1, 1} = 1.5, over the chi²(1) median 0.45494
        let m = s.spread_median.unwrap() * 0.454_936_423_119_572_8;
        assert!((m - 1.5).abs() < 1e-9, "{m}");
        // powers: exact 3 (1 + 6) = 21; run 0: 3 (1.5 + 6) = 22.5; run 1: 3 (0.5 + 9) = 28.5
        let bias = (25.5 - 21.0) / 21.0;
        assert!((s.power_bias.unwrap() - bias).abs() < 1e-12);
        // sample sd of {22.5, 28.5} = sqrt(18), SE = 3
        assert!((s.power_se.unwrap() - 3.0 / 21.0).abs() < 1e-12);
        assert_eq!(s.budget, Some((0.9, 1.1)));
        let none = RunResult {
            variance: None,
            ..runs[0].clone()
        };
        let s = statistics(&[none.clone(), none], Some(&exact), &areas, 100);
        assert_eq!((s.z2, s.no_var, s.spread_pooled), (None, 12, None));
        let notes = ["seed 0: panic: x", "seed 1: panic: x", "converged early: 8"];
        assert_eq!(
            dedup_notes(notes.map(String::from).to_vec()),
            ["2 seeds: panic: x", "converged early: 8"]
        );
        assert_eq!((ratio(2.345), ratio(-3e7)), ("+2.3".into(), "-3e7".into()));
    }

    /// Runs that converged early to the exact answer with variance 0 (gathering in a
    /// furnace): counted as exact, not as misses or in z², and their budget shown apart.
    #[test]
    fn exact_runs_are_exact_not_misses() {
        let exact = [grey(2.0), grey(2.0)];
        let run = RunResult {
            radiosity: exact.to_vec(),
            variance: Some(vec![DVec3::ZERO; 2]),
            rays: 85,
            converged: true,
        };
        let s = statistics(&[run.clone(), run.clone()], Some(&exact), &[1.0, 1.0], 100);
        assert_eq!((s.z2, s.zero_var, s.exact, s.exact_early), (None, 0, 12, 2));
        assert_eq!((s.budget, s.budget_exact_early), (None, Some((0.85, 0.85))));
        // the same answer 1e-6 off is not exact: its variance 0 is a miss
        let off = RunResult {
            radiosity: vec![grey(2.0 + 2e-6); 2],
            ..run.clone()
        };
        let s = statistics(&[off.clone(), off], Some(&exact), &[1.0, 1.0], 100);
        assert_eq!((s.zero_var, s.exact, s.exact_early), (12, 0, 0));
        assert_eq!(s.budget, Some((0.85, 0.85)));
    }

    /// A standard normal number (Box-Muller).
    fn normal(rng: &mut mcrad_random::Stream) -> f64 {
        let (u, v) = (1.0 - rng.uniform_f64(), rng.uniform_f64());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }

    /// Synthetic calibrated runs: B = exact + sigma_i N(0, 1), reported var sigma_i², over
    /// 200 patches, 3 channels and 16 seeds (9600 z²). Mean z² has standard error
    /// sqrt(2 / 9600) = 0.0144, the pooled ratio about sqrt(2/15 / 600) (unequal sigmas
    /// raise it to about 0.03): bounds of 0.1 are > 3 standard errors (false-failure rate
    /// < 0.3%, and the seed is fixed). A miscalibrated variance (reported 4x too small)
    /// must be seen as 4.
    #[test]
    fn statistics_of_calibrated_and_miscalibrated_synthetic_runs() {
        let mut rng = mcrad_random::Stream::new(7, 0, 0, 0);
        let n = 200;
        let exact: Vec<DVec3> = (0..n).map(|i| grey(10.0 + i as f64)).collect();
        let sigma: Vec<f64> = (0..n).map(|i| 0.5 + (i % 7) as f64 * 0.3).collect();
        let areas: Vec<f64> = (0..n).map(|i| 1.0 + (i % 3) as f64).collect();
        let runs = |scale: f64, rng: &mut mcrad_random::Stream| -> Vec<RunResult> {
            (0..16)
                .map(|_| RunResult {
                    radiosity: (0..n)
                        .map(|i| {
                            exact[i] + sigma[i] * DVec3::new(normal(rng), normal(rng), normal(rng))
                        })
                        .collect(),
                    variance: Some((0..n).map(|i| grey(sigma[i].powi(2) / scale)).collect()),
                    rays: 100,
                    converged: false,
                })
                .collect()
        };
        let calibrated = statistics(&runs(1.0, &mut rng), Some(&exact), &areas, 100);
        let z2 = calibrated.z2.unwrap();
        let pooled = calibrated.spread_pooled.unwrap();
        let median = calibrated.spread_median.unwrap();
        assert!((z2 - 1.0).abs() < 0.1, "{calibrated:?}");
        assert!((pooled - 1.0).abs() < 0.1, "{calibrated:?}");
        assert!((median - 1.0).abs() < 0.1, "{calibrated:?}");
        // the power: unbiased, its bias within 3 SE
        let t = calibrated.power_bias.unwrap() / calibrated.power_se.unwrap();
        assert!(t.abs() < 3.0, "{calibrated:?}");
        let small = statistics(&runs(4.0, &mut rng), Some(&exact), &areas, 100);
        assert!((small.z2.unwrap() - 4.0).abs() < 0.4, "{small:?}");
        assert!(
            (small.spread_pooled.unwrap() - 4.0).abs() < 0.4,
            "{small:?}"
        );
        assert!(
            (small.spread_median.unwrap() - 4.0).abs() < 0.4,
            "{small:?}"
        );
    }

    /// Synthetic rare events with a true variance: `B = exact + X - p a`, `X = a` with
    /// probability `p = 1/500` and 0 otherwise, reported variance `a² p (1 - p)` exactly; 200
    /// patches, 3 channels, 16 seeds (9600 entries, about 19 events). The kurtosis of `z` is
    /// about `1/p = 500`, beyond `K / ln 2 = 23`: the median ratio, 0 for the patches without an
    /// event, is not judged, while mean `z²` (about `1 ± 1/sqrt(19)`) and the pooled ratio
    /// stay near 1 (bounds of 0.5 / 0.4: beyond 2 standard errors, fixed seed). Calibrated
    /// normal errors have kurtosis 3 and keep their median judged.
    #[test]
    fn rare_events_defeat_the_median_not_the_pooled_ratio() {
        let mut rng = mcrad_random::Stream::new(11, 0, 0, 0);
        let (n, p, a) = (200, 1.0 / 500.0, 50.0);
        let exact: Vec<DVec3> = (0..n).map(|i| grey(1.0 + i as f64)).collect();
        let areas = vec![1.0; n];
        let mut event = || if rng.uniform_f64() < p { a } else { 0.0 } - p * a;
        let runs: Vec<RunResult> = (0..16)
            .map(|_| RunResult {
                radiosity: exact
                    .iter()
                    .map(|e| *e + DVec3::new(event(), event(), event()))
                    .collect(),
                variance: Some(vec![grey(a * a * p * (1.0 - p)); n]),
                rays: 100,
                converged: false,
            })
            .collect();
        let s = statistics(&runs, Some(&exact), &areas, 100);
        assert!(s.z_kurtosis.unwrap() > 160.0, "{s:?}");
        assert!(s.spread_median.unwrap() < 0.1, "{s:?}");
        assert!(!median_judged(&s, 16));
        assert!((s.z2.unwrap() - 1.0).abs() < 0.5, "{s:?}");
        assert!((s.spread_pooled.unwrap() - 1.0).abs() < 0.5, "{s:?}");
        let normal_runs: Vec<RunResult> = (0..16)
            .map(|_| RunResult {
                radiosity: exact
                    .iter()
                    .map(|e| *e + DVec3::new(normal(&mut rng), normal(&mut rng), normal(&mut rng)))
                    .collect(),
                variance: Some(vec![grey(1.0); n]),
                rays: 100,
                converged: false,
            })
            .collect();
        let s = statistics(&normal_runs, Some(&exact), &areas, 100);
        assert!((s.z_kurtosis.unwrap() - 3.0).abs() < 0.5, "{s:?}");
        assert!(median_judged(&s, 16));
    }

    /// End to end: one small case, one method, two seeds; the furnace answer is checked loosely
    /// (the statistics must exist and the power be near exact), not calibrated.
    /// Issue 36, item 1: `combined` (and `prr`, both under the default `qmc` sampler) keep no
    /// bias in the small-light-and-slivers room of one patch per face. The scene class
    /// had `combined` at -0.143% at 1e6 rays (-28 standard errors over 16 seeds, a bias of order
    /// 1/N, so about -0.7% at the 2e5 rays here); not reproduced on main nor now (64 seeds:
    /// docs/calibration.md). 16 seeds at 2e5 rays: the power of the mean within 3 standard
    /// errors of the reference (the table's target, with its floor of 1e-4 / 3).
    #[test]
    fn small_light_and_slivers_power_is_unbiased() {
        let dir = tempfile::tempdir().unwrap();
        let args = CalibrateArgs {
            seeds: 16,
            rays: 40_000,
            cases: vec!["slivers".into()],
            methods: vec![Method::Combined, Method::Prr],
            limit: DEFAULT_LIMIT,
            out: "calibration.md".into(),
            sampler: None,
            reference_tolerance: target::POWER_TOLERANCE,
            per_patch: None,
        };
        let o = Options::parse(dir.path(), &args).unwrap();
        for r in measure(&o).unwrap() {
            assert_eq!(r.done, 16, "{:?}", r.notes);
            let (bias, se) = (r.stats.power_bias.unwrap(), r.stats.power_se.unwrap());
            let k = bias / se.max(target::POWER_TOLERANCE / target::POWER_SE);
            assert!(
                k.abs() <= target::POWER_SE,
                "{}: power bias {bias:e} = {k:.1} standard errors",
                r.method
            );
        }
    }

    /// A lit case goes through the solve from its scene: the point light's direct light is in
    /// the runs (the power near the reference's), and the pass's variance is reported.
    /// Case `name` measured end to end in `dir`: `prr`, 2 seeds of 2e4 rays; the arguments
    /// its options and the rows.
    fn two_prr_runs(dir: &Path, name: &str) -> (CalibrateArgs, Options, Vec<Row>) {
        let args = CalibrateArgs {
            seeds: 2,
            rays: 20_000,
            cases: vec![name.into()],
            methods: vec![Method::Prr],
            limit: DEFAULT_LIMIT,
            out: "calibration.md".into(),
            sampler: None,
            reference_tolerance: target::POWER_TOLERANCE,
            per_patch: None,
        };
        let o = Options::parse(dir, &args).unwrap();
        let rows = measure(&o).unwrap();
        (args, o, rows)
    }

    #[test]
    fn a_lit_case_runs_end_to_end() {
        let dir = tempfile::tempdir().unwrap();
        let (args, _, rows) = two_prr_runs(dir.path(), "point-faces");
        let s = &rows[0].stats;
        assert_eq!(rows[0].done, 2, "{:?}", rows[0].notes);
        assert_eq!((s.zero_var, s.no_var), (0, 0), "{s:?}");
        // without the light every patch would be 0: a power bias of -100%
        assert!(s.power_bias.unwrap().abs() < 0.05, "{s:?}");
        assert!(s.z2.is_some() && s.spread_pooled.is_some(), "{s:?}");
        let all = Options::parse(
            dir.path(),
            &CalibrateArgs {
                cases: Vec::new(),
                ..args
            },
        )
        .unwrap();
        let names: Vec<_> = all.cases.iter().map(|c| c.name).collect();
        assert!(
            names.contains(&"point-faces") && !names.contains(&"window"),
            "{names:?}"
        );
    }

    #[test]
    fn one_case_runs_end_to_end() {
        let dir = tempfile::tempdir().unwrap();
        let (_, o, rows) = two_prr_runs(dir.path(), "furnace-0.5");
        assert_eq!(rows.len(), 1);
        let s = &rows[0].stats;
        assert_eq!(rows[0].done, 2, "{:?}", rows[0].notes);
        assert!(s.z2.is_some() && s.spread_pooled.is_some(), "{s:?}");
        // shooting conserves power: 20k rays on 864 patches leave it within a few percent
        assert!(s.power_bias.unwrap().abs() < 0.05, "{s:?}");
        let doc = document(&o, &table(&rows, o.reference_tolerance));
        assert!(doc.contains("| furnace-0.5 | prr | 2/2 |"), "{doc}");
    }
}
