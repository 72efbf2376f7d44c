//! Baking a radiosity solution into the user's own glTF scene.
//!
//! The input document is kept whole (nodes, names, materials, textures, extras, unknown
//! extensions); what changes:
//! - every triangle primitive the solver saw gets a second UV set `TEXCOORD_1` into one
//!   lightmap atlas. Its triangles are grouped into **charts** (triangles sharing an edge and a
//!   plane), each flattened at a fixed texel size (scene units per texel) and packed with
//!   `padding` empty texels around it. Vertices on a chart boundary are split (one copy per
//!   chart), so every vertex attribute is copied for the new vertices; strips and fans become
//!   triangle lists;
//! - a mesh placed by several nodes is copied per node (each placement has its own light);
//! - the **lightmap** holds the incident irradiance `H` (W/m², linear RGB) per texel, so that a
//!   viewer shows outgoing radiance `L = albedo H / pi` with the material's own (textured)
//!   albedo: `H = (B - E) / rho` per patch from the solution (`0` where `rho = 0`),
//!   interpolated over the mesh's corners as renders are ([`mcrad_render::interpolate`]),
//!   sampled at the point of the chart nearest to each texel centre, and dilated into the
//!   padding so that bilinear lookups at chart edges never read an empty texel (no seams);
//! - it is embedded as an 8-bit sRGB PNG of `H / intensity` and referenced from every baked
//!   material through the `MOZ_lightmap` extension (`texCoord` 1, `intensity` in W/m²); the
//!   linear values come back as [`Lightmap`] for an EXR beside the GLB;
//! - all buffers and external images move into the GLB's one binary chunk.
//!
//! Deterministic: the charts, the packing and the texel values depend only on the scene, the
//! solution and the options (texels are sampled in parallel and written in a fixed order).

mod atlas;
mod charts;
mod convert;
mod document;

use std::path::Path;

use glam::{DVec2, DVec3, Vec3};
use mcrad_meshing::Mesh;
use mcrad_raycast::{Ray, RayCaster};
use mcrad_scene_io::{GltfSource, LoadOptions, Scene, SceneError};
use rayon::prelude::*;

use crate::charts::Chart;
pub use crate::convert::{glb_from_scene, gltf_from_scene, gltf_scene};
use crate::document::{BakedPrimitive, Document};

/// What went wrong while baking.
#[derive(Debug, thiserror::Error)]
pub enum BakeError {
    /// The texel size is not a positive finite length.
    #[error("the texel size {0} is not a positive finite length")]
    BadTexel(f32),
    /// A chart does not fit the largest atlas at this texel size.
    #[error(
        "a flat part of the scene is {texels:.0} texels across, more than a {limit} x {limit} \
         lightmap holds: choose a larger texel size"
    )]
    ChartTooLarge {
        /// The chart's extent, texels.
        texels: f64,
        /// The largest atlas edge, texels.
        limit: u32,
    },
    /// The charts together do not fit the largest atlas.
    #[error(
        "the lightmap needs about {texels:.0} texels, more than a {limit} x {limit} atlas \
         holds: choose a larger texel size"
    )]
    AtlasFull {
        /// Texels the charts need, padding included.
        texels: f64,
        /// The largest atlas edge, texels.
        limit: u32,
    },
    /// The solution does not belong to the mesh.
    #[error("the solution has {got} values, the mesh has {expected} patches")]
    SolutionLength {
        /// Patches of the mesh.
        expected: usize,
        /// Values given.
        got: usize,
    },
    /// A primitive's vertices are not where the scene has them.
    #[error("primitive instance {0} names vertices the scene does not have")]
    Vertices(usize),
    /// The document cannot be rewritten.
    #[error("{0}")]
    Document(String),
    /// The document uses something baking does not handle yet.
    #[error("not supported yet: {0}")]
    Unsupported(String),
    /// The GLB file cannot be written (too large).
    #[error("{0}")]
    Glb(#[from] mcrad_scene_io::glb::GlbError),
    /// A scene made into a glTF document does not read back as a scene.
    #[error("the scene as glTF: {0}")]
    Convert(#[source] SceneError),
    /// An external image the document names cannot be embedded.
    #[error("image {index}: {cause}")]
    Image {
        /// The image's index in the document.
        index: usize,
        /// Why it cannot be read.
        cause: SceneError,
    },
}

/// How to bake.
#[derive(Debug, Clone, PartialEq)]
pub struct BakeOptions {
    /// Edge of a lightmap texel in scene units (`> 0`); `None`: chosen so that the charts
    /// take about [`DEFAULT_TEXELS`] texels.
    pub texel: Option<f32>,
    /// Texels of dilated padding around each chart (`>= 1`; bilinear filtering needs 1, mip
    /// levels more).
    pub padding: u32,
    /// The largest atlas edge, texels.
    pub max_atlas: u32,
    /// Bake into vertex colours (`COLOR_0`) instead of a lightmap: each vertex, split where
    /// charts meet, takes `H / intensity` at its position.
    pub vertex_colors: bool,
}

/// The chart area, in texels, that the default texel size aims at (half a 1024² atlas).
pub const DEFAULT_TEXELS: f64 = 512.0 * 1024.0;

impl Default for BakeOptions {
    fn default() -> Self {
        BakeOptions {
            texel: None,
            padding: 2,
            max_atlas: 8192,
            vertex_colors: false,
        }
    }
}

/// The baked lightmap in linear values.
#[derive(Debug, Clone, PartialEq)]
pub struct Lightmap {
    /// Edge of the square atlas, texels.
    pub size: u32,
    /// Incident irradiance `H` per texel, W/m² per linear RGB channel, row-major, top row first
    /// (`v = 0` of `TEXCOORD_1`); padding dilated, unused texels 0.
    pub irradiance: Vec<Vec3>,
    /// Texels inside or touching a chart (the rest is padding or unused).
    pub covered: usize,
}

/// A baked document.
#[derive(Debug, Clone)]
pub struct Baked {
    /// The GLB file's bytes.
    pub glb: Vec<u8>,
    /// The lightmap it embeds, linear (`None` for vertex colours).
    pub lightmap: Option<Lightmap>,
    /// The `MOZ_lightmap` intensity (W/m²): a decoded PNG texel of 1 is this irradiance (for
    /// vertex colours: a colour of 1).
    pub intensity: f32,
    /// The texel edge used, scene units.
    pub texel: f32,
    /// Charts in the atlas.
    pub charts: usize,
    /// Primitive placements given lightmap coordinates.
    pub primitives: usize,
    /// The texels' (or, for vertex colours, the vertices') uncertainty, when the solution has
    /// variances.
    pub texel_error: Option<TexelError>,
    /// Per input face (by source number, ascending) that has texels: their mean irradiance and
    /// its variance (empty for vertex colours).
    pub face_texels: Vec<FaceTexels>,
}

/// The texels of one input face.
#[derive(Debug, Clone, PartialEq)]
pub struct FaceTexels {
    /// The face's source number ([`Face::source`](mcrad_scene_io::Face::source)).
    pub source: u32,
    /// Texels it covers or touches.
    pub texels: usize,
    /// Their mean incident irradiance `H`, W/m² per channel.
    pub mean: DVec3,
    /// The variance of that mean from the solution's, (W/m²)² per channel: texels on one patch
    /// share its error, so `k_f sum_p (n_p / n)² var(B_p) / rho_p²` over the patches `p` the
    /// face's `n` texels fall on (`n_p` of them), `k_f` the factor of the correlation between
    /// the patches ([`BakeInput::face_correlation`]; the texels fall on the patches nearly in
    /// proportion to their areas, the weights the factor is for). `None` when the solution
    /// has no variances.
    pub variance: Option<DVec3>,
}

/// What a bake reads: the scene and the document it came from, the mesh solved on, a ray
/// caster over that mesh (ids = patch indices, as [`Mesh::triangle_patch`]) and the radiosity
/// per patch (W/m²).
pub struct BakeInput<'a, C: RayCaster> {
    /// The scene file (external images are named relative to it).
    pub path: &'a Path,
    /// The file policy the scene was read under (applies to the images too).
    pub load_options: &'a LoadOptions,
    /// The scene.
    pub scene: &'a Scene,
    /// The glTF document it was read from.
    pub gltf: &'a GltfSource,
    /// The mesh the solution is on.
    pub mesh: &'a Mesh,
    /// A ray caster over `mesh`.
    pub caster: &'a C,
    /// Radiosity `B` per patch, W/m² per channel.
    pub radiosity: &'a [DVec3],
    /// The estimated variance of `B` per patch, (W/m²)² per channel, when the method gives one.
    pub variance: Option<&'a [DVec3]>,
    /// Per face as outputs number them (its input face, plus [`Mesh::back_face_offset`] for
    /// a back side), per channel, the factor the correlation between its patches' errors puts
    /// on their variances summed as independent (dimensionless, 1 for a face of one patch;
    /// `Solution::face_correlation` of `mcrad-mc-radiosity`): [`FaceTexels::variance`] takes
    /// it. `None` (or a face beyond the slice): the patches are taken as independent.
    pub face_correlation: Option<&'a [DVec3]>,
    /// Told `(charts sampled, charts)` as the texels are sampled (from any thread).
    pub progress: Option<&'a (dyn Fn(u64, u64) + Sync)>,
    /// The direct light drawn per texel (and per vertex) with shadow rays instead of taken
    /// from the solution; `None`: the solution's alone (interpolated).
    pub direct: Option<DirectLight<'a>>,
}

/// Lights without a surface and the sky, whose direct irradiance a bake computes at each
/// texel's point with its own shadow rays ([`DIRECT_SAMPLES`] per light, a sun's direction
/// stratified over its disc; [`SKY_SAMPLES`] towards the sky; streams keyed by the texel),
/// adding it to the solution's irradiance without it.
#[derive(Debug, Clone, Copy)]
pub struct DirectLight<'a> {
    /// The lights (point, spot, sun), in the scene's frame.
    pub lights: &'a [mcrad_scene_io::Light],
    /// The sky whose direct light is drawn per texel too (`None`: no sky, or its direct light
    /// is not in `irradiance`).
    pub sky: Option<&'a mcrad_scene_io::Sky>,
    /// Their direct irradiance `H_d` per patch in the solution (W/m² per channel, mesh
    /// order; the lights' and, with `sky`, the sky's): the solution's `rho H_d` is taken out
    /// of `radiosity` before it is interpolated.
    pub irradiance: &'a [DVec3],
}

/// Shadow rays per light and texel (a 4 x 4 stratified grid over the light's sample domain)
/// of [`DirectLight`].
pub const DIRECT_SAMPLES: u32 = 16;

/// Rays towards the sky per texel of [`DirectLight::sky`] (an 8 x 8 stratified grid of
/// cosine directions; for a map, as many more by its luminance, combined by the balance
/// heuristic: [`mcrad_render::sky_irradiance_sample`]).
pub const SKY_SAMPLES: u32 = 64;

/// The pass number of the bake's direct-light streams.
const DIRECT_PASS: u64 = 0x4241_4b45_4449_5200;

/// The mean direct irradiance (W/m² per channel) of `lights` (in the mesh's frame) at `point`
/// of `patch` (normal `normal`), [`DIRECT_SAMPLES`] shadow rays per light stratified over the
/// light's sample domain, random numbers from the stream of `key`.
fn direct_at<C: RayCaster>(
    caster: &C,
    lights: &[mcrad_scene_io::Light],
    far: f64,
    point: Vec3,
    normal: Vec3,
    patch: u32,
    key: u64,
) -> DVec3 {
    let mut rng = mcrad_random::Stream::new(0, DIRECT_PASS, key, 0);
    let m = DIRECT_SAMPLES.isqrt();
    let from = mcrad_raycast::SurfacePoint::new(point, normal, patch);
    let mut h = DVec3::ZERO;
    for light in lights {
        for a in 0..m {
            for b in 0..m {
                let u = jittered(&mut rng, m, a, b);
                let Some((e, target)) = light.arrival(point, normal, u, far) else {
                    continue;
                };
                if !caster.occluded(&from, &mcrad_raycast::SurfacePoint::free(target)) {
                    h += e;
                }
            }
        }
    }
    h / f64::from(m * m)
}

/// A uniform point of cell `(a, b)` of the `m × m` grid over the unit square.
fn jittered(rng: &mut mcrad_random::Stream, m: u32, a: u32, b: u32) -> [f64; 2] {
    [
        (f64::from(a) + rng.uniform_f64()) / f64::from(m),
        (f64::from(b) + rng.uniform_f64()) / f64::from(m),
    ]
}

/// The sky's direct irradiance (W/m² per channel) at `point` of `patch` (normal `normal`, the
/// mesh's frame): the mean of [`SKY_SAMPLES`] estimates on a stratified grid, random numbers
/// from sub-stream 1 of the stream of `key`.
fn sky_at<C: RayCaster>(
    caster: &C,
    sky: &mcrad_scene_io::Sky,
    far: f64,
    point: Vec3,
    normal: Vec3,
    patch: u32,
    key: u64,
) -> DVec3 {
    let mut rng = mcrad_random::Stream::new(0, DIRECT_PASS, key, 1);
    let m = SKY_SAMPLES.isqrt();
    let mut h = DVec3::ZERO;
    for a in 0..m {
        for b in 0..m {
            let mut cell = || jittered(&mut rng, m, a, b).map(|x| x.min(1.0 - f64::EPSILON));
            let (u, v) = (cell(), cell());
            h += mcrad_render::sky_irradiance_sample(caster, sky, far, point, normal, patch, u, v);
        }
    }
    h / f64::from(m * m)
}

/// How uncertain the baked texels are: over the covered texels, the relative error of each
/// texel's irradiance, taken as that of its patch: the root sum of squares of the Monte Carlo
/// noise (the relative standard error of `H`, [`relative_error`]; interpolation only lowers
/// it) and the mesh's discretization (the patch's [`Mesh::discretization_error`] of `H`
/// relative to its `H`, noise floor subtracted):
/// `total = sqrt(noise² + mesh²)`. Percentiles count texels, so they weigh surfaces by their
/// lightmap area.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TexelError {
    /// Texels counted (covered texels whose patch has a variance).
    pub texels: usize,
    /// The median total relative error (dimensionless; infinite for texels no light
    /// reached).
    pub median: f64,
    /// The 95th percentile of the total.
    pub p95: f64,
    /// The largest total.
    pub max: f64,
    /// The distribution of the noise part alone.
    pub noise: ErrorSpread,
    /// The distribution of the mesh (discretization) part alone.
    pub mesh: ErrorSpread,
}

/// The median, 95th percentile and largest of one part of the texels' relative errors
/// (dimensionless), over the texels of [`TexelError`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ErrorSpread {
    /// The median.
    pub median: f64,
    /// The 95th percentile.
    pub p95: f64,
    /// The largest.
    pub max: f64,
}

impl ErrorSpread {
    /// The spread of `errors`, each counted once; zeros when empty.
    fn of(errors: &[f64]) -> ErrorSpread {
        let ones = vec![1.0; errors.len()];
        let q = |q: f64| weighted_quantile(errors, &ones, q).unwrap_or(0.0);
        ErrorSpread {
            median: q(0.5),
            p95: q(0.95),
            max: errors.iter().copied().fold(0.0, f64::max),
        }
    }
}

pub use mcrad_combine::{relative_error, weighted_quantile};

/// Instance `i`'s triangles over new vertices, one per (vertex, chart) (a triangle in no
/// chart, a degenerate one, shares its vertices' chartless copies): `copies` and `triangles`
/// filled, `uv` and `colors` empty.
fn split_vertices(
    inst: &mcrad_scene_io::PrimitiveInstance,
    chart_of: &[Option<usize>],
) -> BakedPrimitive {
    let mut index: std::collections::HashMap<(u32, usize), u32> = Default::default();
    let mut p = BakedPrimitive {
        node: inst.node,
        mesh: inst.mesh,
        primitive: inst.primitive,
        copies: Vec::new(),
        uv: Vec::new(),
        colors: Vec::new(),
        triangles: Vec::with_capacity(inst.triangles.len()),
    };
    for (k, t) in inst.triangles.iter().enumerate() {
        let chart = chart_of[k].unwrap_or(usize::MAX);
        let mut out = [0u32; 3];
        for (j, &v) in t.iter().enumerate() {
            out[j] = *index.entry((v, chart)).or_insert_with(|| {
                p.copies.push(v);
                (p.copies.len() - 1) as u32
            });
        }
        p.triangles.push(out);
    }
    p
}

/// The irradiance `H = (B - E) / rho` (W/m² per channel) arriving at a patch of radiosity `B`,
/// emission `E` and reflectance `rho`, from `B = E + rho H`; 0 in a channel where `rho` is 0
/// (nothing is reflected, so the solution does not say) and never negative.
pub fn incident(b: DVec3, e: DVec3, rho: DVec3) -> DVec3 {
    let f = |b: f64, e: f64, r: f64| {
        if r > 1e-6 {
            ((b - e) / r).max(0.0)
        } else {
            0.0
        }
    };
    DVec3::new(f(b.x, e.x, rho.x), f(b.y, e.y, rho.y), f(b.z, e.z, rho.z))
}

/// Bakes the solution into the document (see the crate documentation).
pub fn bake<C: RayCaster>(
    input: &BakeInput<'_, C>,
    options: &BakeOptions,
) -> Result<Baked, BakeError> {
    let BakeInput {
        scene, gltf, mesh, ..
    } = *input;
    let patches = mesh.patches();
    let lengths = [
        Some(input.radiosity.len()),
        input.variance.map(<[_]>::len),
        input.direct.map(|d| d.irradiance.len()),
    ];
    if let Some(got) = lengths.into_iter().flatten().find(|&n| n != patches.len()) {
        return Err(BakeError::SolutionLength {
            expected: patches.len(),
            got,
        });
    }
    let positions = scene.positions();
    // world corners of every instance's triangles
    let mut corners: Vec<Vec<Option<[Vec3; 3]>>> = Vec::with_capacity(gltf.instances.len());
    for (i, inst) in gltf.instances.iter().enumerate() {
        let at = |v: u32| positions.get((inst.vertex_offset + v) as usize).copied();
        let mut list = Vec::with_capacity(inst.triangles.len());
        for t in &inst.triangles {
            let c = [at(t[0]), at(t[1]), at(t[2])];
            match c {
                [Some(a), Some(b), Some(c)] => list.push(Some([a, b, c])),
                _ => return Err(BakeError::Vertices(i)),
            }
        }
        corners.push(list);
    }
    let texel = match options.texel {
        Some(t) if t.is_finite() && t > 0.0 => f64::from(t),
        Some(t) => return Err(BakeError::BadTexel(t)),
        None => {
            let area: f64 = corners
                .iter()
                .flatten()
                .flatten()
                .map(|[a, b, c]| {
                    let (a, b, c) = (a.as_dvec3(), b.as_dvec3(), c.as_dvec3());
                    (b - a).cross(c - a).length() / 2.0
                })
                .sum();
            (area / DEFAULT_TEXELS)
                .sqrt()
                .max(f64::from(f32::MIN_POSITIVE))
        }
    };
    let mut charts: Vec<Chart> = Vec::new();
    let mut chart_of: Vec<Vec<Option<usize>>> = Vec::with_capacity(gltf.instances.len());
    for (i, inst) in gltf.instances.iter().enumerate() {
        let first = charts.len();
        let these = charts::charts_of(i, &inst.triangles, &corners[i], texel);
        let mut of = vec![None; inst.triangles.len()];
        for (c, chart) in these.iter().enumerate() {
            for &k in &chart.triangles {
                of[k as usize] = Some(first + c);
            }
        }
        charts.extend(these);
        chart_of.push(of);
    }
    let padding = options.padding.max(1);

    // irradiance per patch, then per mesh corner, interpolated as renders do
    // (without the lights' direct light where it is drawn per texel)
    let h: Vec<DVec3> = patches
        .iter()
        .zip(input.radiosity)
        .enumerate()
        .map(|(i, (p, &b))| {
            let h = incident(b, p.emission.as_dvec3(), p.reflectance.as_dvec3());
            match input.direct {
                Some(d) => (h - d.irradiance[i]).max(DVec3::ZERO),
                None => h,
            }
        })
        .collect();
    let lights: Vec<mcrad_scene_io::Light> = input
        .direct
        .map(|d| {
            d.lights
                .iter()
                .map(|l| l.translated(-mesh.origin()))
                .collect()
        })
        .unwrap_or_default();
    let sky = input.direct.and_then(|d| d.sky).filter(|s| !s.is_dark());
    let far = mesh.escape_distance();
    let corner_h: Vec<Vec3> = mesh
        .seamless_corner_radiosity(&h, mcrad_meshing::DEFAULT_CREASE_ANGLE_DEGREES)
        .iter()
        .map(|v| v.as_vec3())
        .collect();
    // the front normal of each input face (by source number), for the lookup rays
    let mut front: Vec<Option<Vec3>> =
        vec![None; gltf.instances.iter().map(|i| i.triangles.len()).sum()];
    for face in scene.faces() {
        if let Some(slot) = front.get_mut(face.source as usize) {
            slot.get_or_insert(scene.face_normal(face));
        }
    }
    let diagonal = scene.bounds().diagonal();
    let lift = (0.05 * texel).max(1e-5 * diagonal);
    // the scene's (world) points in the mesh's local frame, where its caster works
    let mesh_origin = mesh.origin().as_dvec3();
    // `key`: the texel's (or vertex's) own random stream for the direct light
    let value_at = |point: DVec3, normal: Vec3, key: u64| -> Option<(Vec3, u32)> {
        let point = point - mesh_origin;
        for side in [1.0f32, -1.0] {
            let n = normal * side;
            let origin = (point + n.as_dvec3() * lift).as_vec3();
            let hit = input.caster.closest_hit(&Ray::new(origin, -n))?;
            if f64::from(hit.distance) > 2.0 * lift + 1e-6 * diagonal {
                continue;
            }
            let patch = patches.get(hit.id as usize)?;
            let offset = mesh.corner_offset(hit.id as usize);
            let corners = mesh.corners(patch);
            let values = &corner_h[offset..offset + corners.len()];
            let mut h = mcrad_render::interpolate(mesh.positions(), corners, values, hit.point);
            if let Some(sky) = sky {
                let d = sky_at(input.caster, sky, far, hit.point, patch.normal, hit.id, key);
                h += d.as_vec3();
            }
            if !lights.is_empty() {
                let d = direct_at(
                    input.caster,
                    &lights,
                    far,
                    hit.point,
                    patch.normal,
                    hit.id,
                    key,
                );
                h += d.as_vec3();
            }
            return Some((h, hit.id));
        }
        None
    };
    // per patch: the relative noise and mesh errors of its (full) incident irradiance
    let patch_errors: Option<Vec<(f64, f64)>> = input.variance.map(|variance| {
        // the variance of the interpolated H: Var B / rho² per channel
        let var_h: Vec<DVec3> = patches
            .iter()
            .zip(variance)
            .map(|(p, v)| {
                let rho = p.reflectance.as_dvec3();
                let per = |var: f64, r: f64| if r > 1e-6 { var / (r * r) } else { 0.0 };
                DVec3::new(per(v.x, rho.x), per(v.y, rho.y), per(v.z, rho.z))
            })
            .collect();
        let groups = mesh.corner_groups(mcrad_meshing::DEFAULT_CREASE_ANGLE_DEGREES);
        let e = mesh.discretization_error(&h, Some(&var_h), &groups);
        patches
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let noise = relative_error(input.radiosity[i], p.emission.as_dvec3(), variance[i]);
                let full = incident(
                    input.radiosity[i],
                    p.emission.as_dvec3(),
                    p.reflectance.as_dvec3(),
                );
                (noise, relative_error(full, DVec3::ZERO, e[i] * e[i]))
            })
            .collect()
    });
    let errors_of = |patches_seen: &[u32]| -> Option<TexelError> {
        let per_patch = patch_errors.as_ref()?;
        let (mut noise, mut mesh_part, mut total) = (Vec::new(), Vec::new(), Vec::new());
        for &p in patches_seen {
            let (n, m) = per_patch[p as usize];
            noise.push(n);
            mesh_part.push(m);
            total.push(n.hypot(m));
        }
        let all = ErrorSpread::of(&total);
        Some(TexelError {
            texels: total.len(),
            median: all.median,
            p95: all.p95,
            max: all.max,
            noise: ErrorSpread::of(&noise),
            mesh: ErrorSpread::of(&mesh_part),
        })
    };
    if options.vertex_colors {
        // each (vertex, chart) takes the solution a hair inside its triangle, at the vertex
        let mut baked = Vec::with_capacity(gltf.instances.len());
        let mut seen = Vec::new();
        for (i, inst) in gltf.instances.iter().enumerate() {
            let mut p = split_vertices(inst, &chart_of[i]);
            let mut first_use: Vec<Option<(usize, usize)>> = vec![None; p.copies.len()];
            for (k, t) in p.triangles.iter().enumerate() {
                for (j, &v) in t.iter().enumerate() {
                    first_use[v as usize].get_or_insert((k, j));
                }
            }
            for use_ in first_use {
                let Some((k, j)) = use_ else {
                    p.colors.push(Vec3::ZERO);
                    continue;
                };
                let value = corners[i][k].and_then(|c| {
                    let centroid = (c[0] + c[1] + c[2]).as_dvec3() / 3.0;
                    let at = c[j].as_dvec3();
                    let normal = front
                        .get((inst.first_face as usize) + k)
                        .copied()
                        .flatten()?;
                    let key = (1 << 63) | ((i as u64) << 32) | p.colors.len() as u64;
                    value_at(at + (centroid - at) * 1e-4, normal, key)
                });
                if let Some((_, patch)) = value {
                    seen.push(patch);
                }
                p.colors.push(value.map_or(Vec3::ZERO, |(h, _)| h));
            }
            baked.push(p);
        }
        let intensity = baked
            .iter()
            .flat_map(|p| &p.colors)
            .map(|c| c.max_element())
            .fold(0.0f32, f32::max)
            .max(f32::MIN_POSITIVE);
        for p in &mut baked {
            for c in &mut p.colors {
                *c /= intensity;
            }
        }
        let mut doc = Document::new(&gltf.json, &gltf.buffers, input.path, input.load_options)?;
        doc.bake_colors(&baked, intensity)?;
        return Ok(Baked {
            glb: doc.into_glb()?,
            lightmap: None,
            intensity,
            texel: texel as f32,
            charts: charts.len(),
            primitives: baked.len(),
            texel_error: errors_of(&seen),
            face_texels: Vec::new(),
        });
    }
    let packing = atlas::pack(&charts, padding, options.max_atlas)?;
    let done = std::sync::atomic::AtomicU64::new(0);
    let tiles: Vec<Vec<Option<(Vec3, u32, u32)>>> = charts
        .par_iter()
        .enumerate()
        .map(|(c, chart)| {
            if let Some(progress) = input.progress {
                let n = done.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1;
                progress(n, charts.len() as u64);
            }
            let inst = &gltf.instances[chart.instance];
            let world: Vec<[Vec3; 3]> = chart
                .triangles
                .iter()
                .map(|&k| corners[chart.instance][k as usize].expect("charted"))
                .collect();
            atlas::samples(chart, &world, packing.rects[c], padding, texel)
                .into_iter()
                .enumerate()
                .map(|(t, s)| {
                    let s = s?;
                    let k = chart.triangles[s.triangle as usize];
                    let source = (inst.first_face + k) as usize;
                    let normal = front
                        .get(source)
                        .copied()
                        .flatten()
                        .unwrap_or(chart.axes[2].as_vec3());
                    let key = ((c as u64) << 32) | t as u64;
                    value_at(s.point, normal, key).map(|(h, patch)| (h, patch, source as u32))
                })
                .collect()
        })
        .collect();
    let size = packing.size;
    let mut image: Vec<Option<Vec3>> = vec![None; (size as usize) * (size as usize)];
    let mut covered = 0;
    let mut texel_patches = Vec::new();
    // per input face: texels, the sum of their values, and how many fell on each patch
    let mut per_face: std::collections::BTreeMap<u32, (usize, DVec3, Vec<u32>)> =
        Default::default();
    for (c, tile) in tiles.iter().enumerate() {
        let [x0, y0] = packing.corners[c];
        let [w, _] = packing.rects[c];
        for (k, v) in tile.iter().enumerate() {
            if let Some((v, patch, source)) = v {
                let (x, y) = (x0 + k as u32 % w, y0 + k as u32 / w);
                image[(y * size + x) as usize] = Some(*v);
                texel_patches.push(*patch);
                covered += 1;
                let face = per_face.entry(*source).or_default();
                face.0 += 1;
                face.1 += v.as_dvec3();
                face.2.push(*patch);
            }
        }
    }
    let face_texels = per_face
        .into_iter()
        .map(|(source, (n, sum, mut hit))| {
            let variance = input.variance.map(|variance| {
                hit.sort_unstable();
                let mut v = DVec3::ZERO;
                for group in hit.chunk_by(|a, b| a == b) {
                    let p = group[0] as usize;
                    let rho = patches[p].reflectance.as_dvec3();
                    let share = group.len() as f64 / n as f64;
                    let per = |var: f64, r: f64| if r > 1e-6 { var / (r * r) } else { 0.0 };
                    let vh = DVec3::new(
                        per(variance[p].x, rho.x),
                        per(variance[p].y, rho.y),
                        per(variance[p].z, rho.z),
                    );
                    v += share * share * vh;
                }
                let back = mesh.back_face_offset();
                let p = &patches[hit[0] as usize];
                let key = (p.face + if p.back { back } else { 0 }) as usize;
                let k = input
                    .face_correlation
                    .and_then(|k| k.get(key))
                    .copied()
                    .unwrap_or(DVec3::ONE);
                k * v
            });
            FaceTexels {
                source,
                texels: n,
                mean: sum / n as f64,
                variance,
            }
        })
        .collect();
    let texel_error = errors_of(&texel_patches);
    let irradiance = atlas::dilate(&mut image, size, padding + 1);

    // the primitives' new vertices: one per (vertex, chart), placed in the atlas
    let mut baked = Vec::with_capacity(gltf.instances.len());
    for (i, inst) in gltf.instances.iter().enumerate() {
        let mut p = split_vertices(inst, &chart_of[i]);
        let mut uv = vec![DVec2::ZERO; p.copies.len()];
        for (k, t) in p.triangles.iter().enumerate() {
            let Some(c) = chart_of[i][k] else { continue };
            for (j, &v) in t.iter().enumerate() {
                let q = charts[c].flatten(corners[i][k].expect("listed")[j].as_dvec3(), texel);
                let [x, y] = packing.corners[c];
                uv[v as usize] = (DVec2::new(f64::from(x), f64::from(y)) + f64::from(padding) + q)
                    / f64::from(size);
            }
        }
        p.uv = uv;
        baked.push(p);
    }
    let (png, intensity) = document::lightmap_png(&irradiance, size)?;
    let mut doc = Document::new(&gltf.json, &gltf.buffers, input.path, input.load_options)?;
    doc.bake(&baked, &png, intensity)?;
    Ok(Baked {
        glb: doc.into_glb()?,
        lightmap: Some(Lightmap {
            size,
            irradiance,
            covered,
        }),
        intensity,
        texel: texel as f32,
        charts: charts.len(),
        primitives: baked.len(),
        texel_error,
        face_texels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn incident_irradiance_inverts_the_radiosity_equation() {
        let h = incident(
            DVec3::new(3.0, 2.0, 1.0),
            DVec3::new(1.0, 0.0, 0.0),
            DVec3::new(0.5, 0.25, 0.0),
        );
        assert_eq!(h, DVec3::new(4.0, 8.0, 0.0));
    }
}
