//! The command line (its flags are the contract of `docs/cli.md`).

use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use clap::{Parser, Subcommand, ValueEnum};
use mcrad_mc_radiosity::{
    ControlVariate, DEFAULT_RAYS, DEFAULT_UNSHOT_THRESHOLD, Method, Sampler, UnknownName,
};
use mcrad_meshing::DEFAULT_MAX_EDGE_FRACTION;
use mcrad_reference::DEFAULT_VISIBILITY_TOLERANCE;
use mcrad_render::{Exposure, RenderSettings};
use mcrad_solve::{Budget, MeshPlan, Settings};
use std::path::PathBuf;
use std::str::FromStr;

/// Stochastic (Monte Carlo) radiosity.
#[derive(Debug, Parser)]
#[command(name = "mcrad", version, about)]
pub struct Args {
    #[command(subcommand)]
    pub command: Command,
}

// Parsed once per process: the size of the larger variant costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Subcommand)]
pub enum Command {
    /// Solve a scene's radiosity and write the results.
    Solve(Solve),
    /// Combine independent runs of one scene (different seeds) into one solution, per patch
    /// and channel by inverse variance.
    Merge(crate::merge::Merge),
    /// Solve a glTF scene and bake its light into a copy of it: lightmap coordinates
    /// (TEXCOORD_1) on the user's own primitives and an embedded lightmap (MOZ_lightmap), the
    /// rest of the document kept. Takes every option of `solve`.
    Bake(Bake),
}

#[derive(Debug, clap::Args)]
pub struct Bake {
    #[command(flatten)]
    pub solve: Solve,
    /// The baked scene (.glb). The lightmap's linear values (incident irradiance, W/m²) are
    /// written beside it as OUT.lightmap.exr.
    #[arg(long, value_name = "OUT.glb")]
    pub out: PathBuf,
    /// Lightmap texel edge in scene units. Default: the size that gives the scene's surfaces
    /// about half a 1024 x 1024 lightmap.
    #[arg(long, value_name = "L", allow_negative_numbers = true, value_parser = parse_length)]
    pub texel: Option<f32>,
    /// Stop the solve once the 95th percentile (by area) of the patches' relative error of
    /// incident irradiance, noise and mesh (root sum of squares), is at most E (e.g. 0.02),
    /// or at --rays/--time, whichever comes first. Methods without variances ignore it.
    #[arg(long, value_name = "E", value_parser = parse_fraction)]
    pub target_error: Option<f64>,
    /// Bake into vertex colours (COLOR_0 on the scene's own vertices, split where flat parts
    /// meet, times any COLOR_0 they had) instead of a lightmap.
    #[arg(long, conflicts_with = "texel")]
    pub vertex_colors: bool,
}

/// Where `mcrad bake` writes, carried through the solve.
#[derive(Debug, Clone, PartialEq)]
pub struct BakeTarget {
    /// The baked GLB.
    pub out: PathBuf,
    /// `--texel`.
    pub texel: Option<f32>,
    /// `--target-error`.
    pub target_error: Option<f64>,
    /// `--vertex-colors`.
    pub vertex_colors: bool,
}

#[derive(Debug, clap::Args)]
pub struct Solve {
    /// The scene: .obj (with the .mtl files it names), .gltf or .glb.
    pub scene: PathBuf,
    /// Solution method.
    #[arg(long, default_value_t = Method::default(), value_parser = method_parser())]
    pub method: Method,
    /// Total ray budget over all passes (accepts 2000000 and 2e6). Default: `DEFAULT_RAYS`, or
    /// no limit with --time.
    #[arg(long, value_parser = parse_count, help = rays_help())]
    pub rays: Option<u64>,
    /// Wall-clock budget in seconds, counted from the start of loading: after each step the
    /// rest of the run is sized to the rays that fit in the time left at the speed so far (a
    /// shorter last pass), and a step that cannot finish in time is not started.
    #[arg(long, value_name = "S", value_parser = parse_seconds)]
    pub time: Option<f64>,
    /// The most memory the solve may take at its peak, in bytes (accepts 4000000000, 4e9 and
    /// the binary suffixes K, M, G, T: 4G is 4 GiB). A scene whose estimated peak (from its
    /// face count and the mesh plan, before any meshing) exceeds it is refused with the
    /// estimate. Default: the machine's RAM less a tenth (at least 256 MiB less).
    #[arg(long, value_name = "BYTES", value_parser = parse_bytes)]
    pub max_memory: Option<u64>,
    /// Add the ambient term (paper, section 3.1) to shooting solutions.
    #[arg(long)]
    pub ambient: bool,
    /// How rays are drawn: `random` (independent pseudo-random rays) or `qmc` (each patch's
    /// rays from its own Owen-scrambled Sobol sequence, stratified in point and direction).
    /// Either way the answer is unbiased and the same on any thread count.
    #[arg(long, default_value_t = Sampler::default(), value_parser = sampler_parser())]
    pub sampler: Sampler,
    /// Patch gathering with a control variate: `constant` subtracts from what each ray sees
    /// the mean its patch's hits saw in the round before, and adds it back times the share of
    /// the patch's hemisphere that sees the scene, measured by the rounds before that; unbiased
    /// in open scenes too. `off`: plain gathering.
    #[arg(long, default_value_t = ControlVariate::default(), value_parser = control_variate_parser())]
    pub control_variate: ControlVariate,
    /// Adaptive plan: how groups of small neighbouring faces that the refinement shows evenly
    /// lit serve the solve. `transport`: each group is one element of the transport (its rays
    /// shared by its faces, each face keeping its own reflectance and texture); `pool`: every
    /// face an element of its own, the groups' estimates pooled after (docs/meshing.md).
    #[arg(long, value_enum, default_value_t = ClusterArg::Transport)]
    pub clusters: ClusterArg,
    /// reference: the target error of each form-factor row's visibility, relative to the row
    /// sum (one standard deviation of the shadow-ray estimate). Halving it doubles the rays;
    /// 2e-3 is about twenty times quicker than the default.
    #[arg(long, value_name = "F", help = visibility_help())]
    pub visibility_tolerance: Option<f64>,
    /// two-pass: compute direct light by sampling the emitters with shadow rays and gather only
    /// the indirect light (Shirley and Wang 1991); `--method two-pass --split` is an alias of
    /// `--method two-pass-split`. Other methods ignore it.
    #[arg(long)]
    pub split: bool,
    /// A reference solution (a --patches CSV of the same mesh) to measure error against.
    #[arg(long, value_name = "R.csv", requires = "trace")]
    pub reference: Option<PathBuf>,
    /// Write the error against --reference after each step: `seconds,rays,rms_rel`.
    #[arg(long, value_name = "T.csv", requires = "reference")]
    pub trace: Option<PathBuf>,
    /// Seed of all random streams: the same seed gives the same answer on any thread count.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Worker threads, 1 to 256 (default: all cores). The answer is the same on any count.
    #[arg(long, value_parser = clap::value_parser!(u16).range(1..=MAX_THREADS))]
    pub threads: Option<u16>,
    /// One patch per input face, faces in file order.
    #[arg(long, conflicts_with = "max_edge")]
    pub no_subdivide: bool,
    /// How faces become patches: `adaptive` (the default: a mesh of half the uniform default's
    /// edge refined where the solution needs it, within --min-edge and --max-patches;
    /// a quarter of the ray budget or of --time goes to the refinement, then the method solves
    /// the refined mesh, whose solution is the answer) or
    /// `uniform` (every face cut to --max-edge, or the default size). The options that need a
    /// fixed mesh, --max-edge, --no-subdivide, --reference and --method reference, imply
    /// uniform; --save keeps the adaptive mesh in the state and --resume continues on it.
    #[arg(long, value_enum, value_name = "KIND")]
    pub mesh: Option<MeshArg>,
    /// Adaptive meshes: no element edge below L (scene units), and no group of small faces
    /// split below 2 L across. Default: the scene's bounding-box diagonal / 640.
    #[arg(long, value_name = "L", allow_negative_numbers = true, value_parser = parse_length)]
    pub min_edge: Option<f32>,
    /// Adaptive meshes: at most N elements, or one per input face plus N/2 when that is more
    /// (a scene of many small faces keeps each whole and still refines its large ones).
    /// Default: 40000, raised as the refinement goes to one element per 1000 rays of the run
    /// (its rays, or those its time fits), at most 640000 and what --max-memory leaves room for
    #[arg(long, value_name = "N")]
    pub max_patches: Option<usize>,
    /// Subdivide until no patch edge is longer than L (scene units). Default: the scene's
    /// bounding-box diagonal × `DEFAULT_MAX_EDGE_FRACTION`.
    #[arg(long, value_name = "L", allow_negative_numbers = true, value_parser = parse_length, help = max_edge_help())]
    pub max_edge: Option<f32>,
    /// End shooting's waves when the unshot power is below this fraction of the emitted power;
    /// a Russian-roulette tail then ships the rest (no bias). The default is small: a run
    /// spends its budget. The paper's 0.01 ends the waves sooner.
    #[arg(long, default_value_t = DEFAULT_UNSHOT_THRESHOLD, value_name = "FRACTION")]
    pub unshot_threshold: f64,
    /// Write per-patch radiosity: `patch,area,r,g,b,var_r,var_g,var_b,face` (`face`: the input
    /// face the patch belongs to).
    #[arg(long, value_name = "F.csv")]
    pub patches: Option<PathBuf>,
    /// --patches writes one row per input face instead (`patch` is the face number), the
    /// area-weighted mean of its patches, with the header `patch,area,r,g,b,var_r,var_g,var_b`.
    #[arg(long, requires = "patches")]
    pub per_face: bool,
    /// Write run statistics as JSON, with the closure report: per channel the power emitted,
    /// absorbed and escaped (W) and the standard error of their balance.
    #[arg(long, value_name = "F.json")]
    pub stats: Option<PathBuf>,
    /// Render the solution: .png (tone-mapped sRGB) or .exr (linear radiance, W/(m² sr)).
    #[arg(long, value_name = "F.png|F.exr")]
    pub image: Option<PathBuf>,
    /// Render the solution's estimated relative error per pixel (.exr, with the camera, size
    /// and samples of --image): red the total, green the Monte Carlo noise, blue the mesh's
    /// discretization (the total is their root sum of squares); 0 where a ray sees no surface,
    /// 1e30 where no light reached one.
    #[arg(long, value_name = "F.exr")]
    pub error_image: Option<PathBuf>,
    /// Write the mesh with baked per-vertex radiosity (COLOR_0, and exact values in `_RADIOSITY`).
    #[arg(long, value_name = "F.glb")]
    pub gltf: Option<PathBuf>,
    /// Pinhole camera: eye=X,Y,Z,look=X,Y,Z with optional ,up=X,Y,Z and ,fov=DEGREES (vertical
    /// fov, default 40).
    /// Default: the scene file's camera, else one framed automatically.
    #[arg(long, value_name = "SPEC", value_parser = mcrad_render::parse_camera, allow_hyphen_values = true)]
    pub camera: Option<mcrad_render::Camera>,
    /// Image size in pixels.
    #[arg(long, value_name = "WxH", default_value = "512x512", value_parser = parse_size)]
    pub size: (u32, u32),
    /// Rays per pixel (anti-aliasing); a square number is stratified.
    #[arg(long, value_name = "N", default_value_t = RenderSettings::default().samples_per_pixel, value_parser = clap::value_parser!(u32).range(1..=4096))]
    pub spp: u32,
    /// PNG exposure: `auto` (the 99th percentile of luminance maps near white) or stops
    /// (radiance × 2^stops; 0 shows 1 W/(m² sr) as white).
    #[arg(long, value_name = "auto|STOPS", default_value = "auto", value_parser = parse_exposure, allow_hyphen_values = true)]
    pub exposure: Exposure,
    /// Shading of renders: smooth (radiosity reconstructed at vertices, interpolated) or flat
    /// (one colour per patch).
    #[arg(long, value_enum, default_value_t = ShadingArg::Smooth)]
    pub shading: ShadingArg,
    /// Draw punctual lights' and the sun's direct light in renders and bakes from the solved
    /// mesh (interpolated over its vertices) instead of with shadow rays per pixel sample and
    /// lightmap texel (the default with such lights: sharp shadows at any mesh size).
    #[arg(long)]
    pub no_direct_rays: bool,
    /// Draw the sky's direct light in renders with N rays towards the sky per pixel sample
    /// (stratified over the pixel's samples together; 16 is a good choice) and in bakes with
    /// 64 per texel, instead of from the solved mesh (0, the default: interpolated with the
    /// indirect light). Costs N rays per sample; fewer than 16 may add more noise than the
    /// interpolation's error it removes.
    #[arg(long, value_name = "N", default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=256))]
    pub sky_rays: u32,
    /// Final gather in renders: each pixel sample gathers the light arriving at its own
    /// point with N cosine-distributed rays that read the solution where they land (and the
    /// sky where they leave), so the picture shows the mesh's light one bounce away, not its
    /// elements; direct light from lights and the sun is drawn per sample as well. Costs N
    /// rays per sample; 0 shows the solution where a camera ray lands. Not with
    /// `--no-direct-rays` (which `auto` follows with 0). `auto` (the default)
    /// gathers when the budget affords every pixel 512 rays or more: up to 1024 a pixel, in at
    /// most two thirds of the time left once the mesh is built (`--time`) or half as many rays
    /// as the solve cast (`--rays`); otherwise 0.
    #[arg(long, value_name = "N|auto", default_value = "auto", value_parser = parse_gather)]
    pub gather_rays: GatherRays,
    /// Vertex radiosity averages only across patches whose normals differ by less than this
    /// (degrees), and never across materials.
    #[arg(long, value_name = "DEGREES", default_value_t = mcrad_meshing::DEFAULT_CREASE_ANGLE_DEGREES)]
    pub crease: f32,
    /// Write the run's state (solution, variances, rays) to S after every complete step,
    /// atomically, so that `--resume S` can continue it.
    #[arg(long, value_name = "S")]
    pub save: Option<PathBuf>,
    /// Continue the run saved in S (by `--save`): this run's --rays or --time are added to it
    /// as an independent piece with its own random streams, merged by rays. The method, seed,
    /// mesh and options are the saved run's; one given again must agree.
    #[arg(long, value_name = "S")]
    pub resume: Option<PathBuf>,
    /// No progress bar and no summary line (errors and warnings still go to stderr).
    #[arg(long, short)]
    pub quiet: bool,
    /// Read files the scene names (OBJ mtllib, glTF buffer URIs) even outside the scene
    /// file's folder: absolute paths, file: URIs, '..' that climbs out of it, links out of it.
    /// Without it they are refused.
    #[arg(long)]
    pub allow_outside_paths: bool,
    /// The sun: X,Y,Z the direction towards it (any length), E the irradiance in W/m² on a
    /// surface facing it, DIAM its angular diameter in degrees (default 0.53; 0 is a single
    /// direction). Added to the scene's own lights.
    #[arg(long, value_name = "X,Y,Z,E[,DIAM]", allow_negative_numbers = true, value_parser = parse_sun)]
    pub sun: Option<mcrad_scene_io::Light>,
    /// A uniform sky: radiance R,G,B in W/(m² sr) arriving from every direction in which a
    /// ray leaves the scene (a surface open to the whole upper sky receives pi L W/m²).
    #[arg(long, value_name = "R,G,B", value_parser = parse_sky, conflicts_with = "sky_map")]
    pub sky: Option<glam::DVec3>,
    /// A sky from an equirectangular map (.exr or .hdr, twice as wide as high) of radiance in
    /// W/(m² sr): +Y up, the top row the zenith, the centre column looking along -Z, three
    /// quarters across along +X.
    #[arg(long, value_name = "F")]
    pub sky_map: Option<PathBuf>,
    /// Turn the --sky-map about +Y by DEG degrees, counter-clockwise seen from above (at 90
    /// the map's centre looks along -X).
    #[arg(long, value_name = "DEG", default_value_t = 0.0, allow_negative_numbers = true, value_parser = parse_degrees, requires = "sky_map")]
    pub sky_rotate: f64,
    /// The luminous efficacy K (lm/W) that turns glTF lights' photometric intensities into
    /// radiometric ones: I cd radiates I/K W/sr, E_v lux gives E_v/K W/m². 683 round-trips
    /// Blender's exporter; 1 reads the intensities as radiometric.
    #[arg(long, value_name = "K", default_value_t = mcrad_scene_io::DEFAULT_LIGHT_EFFICACY, value_parser = parse_fraction)]
    pub light_efficacy: f64,
    /// Make every face of an OBJ scene two-sided: both sides reflect (and emit, if the
    /// material emits), each with its own radiosity. glTF scenes refuse it: each material's
    /// doubleSided decides.
    #[arg(long)]
    pub two_sided: bool,
    /// Set by `mcrad bake`: bake the solution into the scene's glTF.
    #[arg(skip)]
    pub bake: Option<BakeTarget>,
    /// The ids of the flags given on the command line (not defaulted), set by `main`: a
    /// continued run takes the saved settings where no flag says otherwise.
    #[arg(skip)]
    pub given: Vec<String>,
}

/// The most worker threads `--threads` accepts: more only add overhead (the answer does not
/// depend on the count).
pub const MAX_THREADS: i64 = 256;

impl Solve {
    /// The sky the flags ask for: `--sky`, or `--sky-map` read and turned by `--sky-rotate`.
    pub fn sky(&self) -> Result<Option<mcrad_scene_io::Sky>, mcrad_scene_io::SceneError> {
        match (&self.sky_map, self.sky) {
            (Some(path), _) => {
                mcrad_scene_io::Sky::load_map(path, self.sky_rotate.to_radians()).map(Some)
            }
            (None, Some(l)) => Ok(Some(mcrad_scene_io::Sky::Uniform(l))),
            (None, None) => Ok(None),
        }
    }

    /// The method to run: `--method`, with `--split` turning `two-pass` into `two-pass-split`
    /// (other methods ignore `--split`).
    pub fn method(&self) -> Method {
        match self.method {
            Method::TwoPass if self.split => Method::TwoPassSplit,
            m => m,
        }
    }

    /// The settings the flags ask for, defaults where not given.
    pub fn settings(&self) -> Settings {
        self.settings_over(Settings::default(), true)
    }

    /// The settings of a continued run: `saved`, except what the user gave on the command
    /// line (the library then checks that it agrees with `saved`); with `all`, every setting
    /// from the flags.
    pub fn settings_over(&self, saved: Settings, all: bool) -> Settings {
        let given = |ids: &[&str]| all || ids.iter().any(|id| self.given.iter().any(|g| g == id));
        Settings {
            method: match (given(&["method"]), given(&["split"])) {
                (true, _) => self.method(),
                // `--split` alone applies to the saved method
                (false, true) if saved.method == Method::TwoPass && self.split => {
                    Method::TwoPassSplit
                }
                _ => saved.method,
            },
            mesh: self.mesh_over(saved.mesh, &given),
            seed: if given(&["seed"]) {
                self.seed
            } else {
                saved.seed
            },
            sampler: if given(&["sampler"]) {
                self.sampler
            } else {
                saved.sampler
            },
            control_variate: if given(&["control_variate"]) {
                self.control_variate
            } else {
                saved.control_variate
            },
            ambient: if given(&["ambient"]) {
                self.ambient
            } else {
                saved.ambient
            },
            unshot_threshold: if given(&["unshot_threshold"]) {
                self.unshot_threshold
            } else {
                saved.unshot_threshold
            },
            visibility_tolerance: if given(&["visibility_tolerance"]) {
                self.visibility_tolerance
                    .unwrap_or(DEFAULT_VISIBILITY_TOLERANCE)
            } else {
                saved.visibility_tolerance
            },
        }
    }

    /// The saved mesh plan `saved` with the mesh flags that were given (`given`) applied: the
    /// plan's kind from `--no-subdivide`, `--max-edge` or `--mesh` when one of them is given,
    /// its bounds from `--max-edge`, `--max-patches` and `--min-edge` when given.
    fn mesh_over(&self, saved: MeshPlan, given: &dyn Fn(&[&str]) -> bool) -> MeshPlan {
        let kind_given = given(&["mesh", "no_subdivide", "max_edge"]);
        let plan = if kind_given { self.mesh_plan() } else { saved };
        match (plan, saved) {
            (
                MeshPlan::Adaptive {
                    max_patches,
                    min_edge,
                },
                MeshPlan::Adaptive {
                    max_patches: saved_max,
                    min_edge: saved_min,
                },
            ) => MeshPlan::Adaptive {
                max_patches: if given(&["max_patches"]) {
                    max_patches
                } else {
                    saved_max
                },
                min_edge: if given(&["min_edge"]) {
                    min_edge
                } else {
                    saved_min
                },
            },
            // bounds of an adaptive mesh asked of a saved fixed one: they disagree
            _ if !kind_given && given(&["max_patches", "min_edge"]) => MeshPlan::Adaptive {
                max_patches: self.max_patches,
                min_edge: self.min_edge,
            },
            (plan, _) => plan,
        }
    }

    /// The mesh plan of the flags: `--no-subdivide`, `--mesh`, `--max-edge`, `--max-patches`,
    /// `--min-edge`.
    fn mesh_plan(&self) -> MeshPlan {
        if self.no_subdivide {
            MeshPlan::PerFace
        } else if self.adaptive() {
            MeshPlan::Adaptive {
                max_patches: self.max_patches,
                min_edge: self.min_edge,
            }
        } else {
            MeshPlan::Uniform {
                max_edge: self.max_edge,
            }
        }
    }

    /// The budget of the flags (`--rays`, `--time`, a bake's `--target-error`), the time
    /// counted from `since`.
    pub fn budget(&self, since: std::time::Instant) -> Budget {
        Budget {
            rays: self.rays,
            seconds: self.time,
            since: Some(since),
            target_error: self.bake.as_ref().and_then(|b| b.target_error),
            memory: self.max_memory.or_else(default_max_memory),
        }
    }
}

impl Solve {
    /// Options given that do nothing with the chosen method, one `warning: ` message each
    /// (without the prefix); the run goes on without them.
    pub fn warnings(&self) -> Vec<String> {
        let method = self.method();
        let mut warnings = Vec::new();
        if self.ambient && !method.uses_ambient() {
            warnings.push(format!(
                "--ambient has no effect with --method {method} (it adds the ambient term to \
                 shooting solutions: shoot, prr, two-pass, two-pass-split, progressive-gather, \
                 progressive-two-pass)"
            ));
        }
        if self.visibility_tolerance.is_some() && method != Method::Reference {
            warnings.push(format!(
                "--visibility-tolerance applies to --method reference only; ignored with --method {method}"
            ));
        }
        if !self.adaptive() && self.min_edge.is_some() {
            warnings.push("--min-edge applies to --mesh adaptive only; ignored".into());
        }
        if !self.adaptive() && self.max_patches.is_some() {
            warnings.push("--max-patches applies to --mesh adaptive only; ignored".into());
        }
        if self.split && !matches!(method, Method::TwoPassSplit) {
            warnings.push(format!(
                "--split applies to --method two-pass only; ignored with --method {method}"
            ));
        }
        warnings
    }
}

/// The help of `--visibility-tolerance`, with the reference solver's default.
fn visibility_help() -> String {
    format!(
        "reference: the target error of each form-factor row's visibility, relative to the row \
         sum (one standard deviation of the shadow-ray estimate). Halving it doubles the rays; \
         2e-3 is about twenty times quicker than the default. Default: {DEFAULT_VISIBILITY_TOLERANCE:e}"
    )
}

/// The help of `--rays`, with the library's default budget.
fn rays_help() -> String {
    format!(
        "Total ray budget over all passes (accepts 2000000 and 2e6). Default: {:e}, or no limit \
         with --time",
        DEFAULT_RAYS as f64
    )
}

/// A parser of the names `values` lists (with their help), each read by `T`'s `FromStr`: the
/// listing of possible values in `--help` and clap's error for any other name.
fn named<T>(values: impl IntoIterator<Item = PossibleValue>) -> impl TypedValueParser<Value = T>
where
    T: FromStr<Err = UnknownName> + Clone + Send + Sync + 'static,
{
    PossibleValuesParser::new(values).try_map(|s| s.parse::<T>())
}

/// `--method`: the registry's names, each with its summary and where the paper describes it.
fn method_parser() -> impl TypedValueParser<Value = Method> {
    named(Method::ALL.map(|m| {
        let help = match m.paper() {
            Some(paper) => format!("{} (paper, {paper})", m.summary()),
            None => m.summary().to_string(),
        };
        PossibleValue::new(m.name()).help(help)
    }))
}

/// `--clusters`: `transport` and `pool` ([`mcrad_solve::Clustering`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ClusterArg {
    /// Each evenly lit group of small faces is one element of the transport.
    Transport,
    /// Every face an element of its own; the groups' estimates pooled after.
    Pool,
}

impl From<ClusterArg> for mcrad_solve::Clustering {
    fn from(c: ClusterArg) -> Self {
        match c {
            ClusterArg::Transport => mcrad_solve::Clustering::Transport,
            ClusterArg::Pool => mcrad_solve::Clustering::Pool,
        }
    }
}

/// `--sampler`: `random` and `qmc`.
fn sampler_parser() -> impl TypedValueParser<Value = Sampler> {
    named(Sampler::ALL.map(|s| {
        PossibleValue::new(s.name()).help(match s {
            Sampler::Random => "Independent pseudo-random rays ([`mcrad_random::Stream`])",
            Sampler::Qmc => {
                "Randomised quasi-Monte Carlo: the rays of a patch are the points of its own \
                 Owen-scrambled Sobol sequence ([`mcrad_random::Sobol`]), indexed by the \
                 patch's ray counter (in shooting, continued across waves), so they are \
                 stratified in point and direction; each patch and pass has an independent \
                 scramble. The sequence interleaves two independent scrambles, whose difference \
                 scales the estimators' variances to the stratified rays' true error (the module \
                 `replicates` of this crate has the maths)"
            }
        })
    }))
}

/// `--control-variate`: `off` and `constant`.
fn control_variate_parser() -> impl TypedValueParser<Value = ControlVariate> {
    named(ControlVariate::ALL.map(|c| {
        PossibleValue::new(c.name()).help(match c {
            ControlVariate::Off => {
                "Plain gathering: a patch's estimate is the mean of what its rays see"
            }
            ControlVariate::Constant => {
                "A constant control variate per patch, `beta_i` from its last round and the \
                 coverage `S_i` of its hemisphere from the rounds before: unbiased in open \
                 scenes (the module documentation of `control`)"
            }
        })
    }))
}

/// The help of `--max-edge`, with the library's default subdivision.
fn max_edge_help() -> String {
    format!(
        "Subdivide until no patch edge is longer than L (scene units). Default: the scene's \
         bounding-box diagonal / {}",
        1.0 / DEFAULT_MAX_EDGE_FRACTION
    )
}

/// How faces become patches.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum MeshArg {
    /// A uniform mesh of half the uniform default's edge refined where the solution
    /// varies beyond its noise or the light's visibility changes (the default).
    Adaptive,
    /// Every face cut uniformly (`--max-edge`, or the scene's diagonal / 20).
    Uniform,
}

impl Solve {
    /// Whether the mesh is adaptive: `--mesh adaptive`, or no `--mesh` and none of the options
    /// that need a fixed mesh (a uniform size, one patch per face, a reference compared patch
    /// by patch, the deterministic reference solver).
    pub fn adaptive(&self) -> bool {
        match self.mesh {
            Some(MeshArg::Adaptive) => true,
            Some(MeshArg::Uniform) => false,
            None => !self.needs_fixed_mesh(),
        }
    }

    /// Whether an option asks for a fixed (uniform) mesh.
    fn needs_fixed_mesh(&self) -> bool {
        self.max_edge.is_some()
            || self.no_subdivide
            || self.reference.is_some()
            || self.method().kind() == mcrad_mc_radiosity::Kind::Deterministic
    }

    /// Refuses option combinations that contradict each other.
    pub fn check_mesh_options(&self) -> Result<(), String> {
        if self.adaptive() {
            if self.max_edge.is_some() {
                return Err("--max-edge sets a uniform mesh; use --min-edge and --max-patches to bound --mesh adaptive".into());
            }
            if self.no_subdivide {
                return Err("--no-subdivide sets one patch per face; it cannot be combined with --mesh adaptive".into());
            }
            if self.reference.is_some() {
                return Err("--reference compares patch by patch with a fixed mesh; use it with --mesh uniform".into());
            }
            if self.method().kind() == mcrad_mc_radiosity::Kind::Deterministic {
                return Err(
                    "--method reference solves a fixed mesh; use it with --mesh uniform".into(),
                );
            }
            if self.max_patches == Some(0) {
                return Err("--max-patches must be at least 1".into());
            }
        }
        if self.no_direct_rays && self.gather_rays.0.is_some_and(|n| n > 0) {
            return Err(
                "--gather-rays draws the lights' direct light per sample; it cannot be \
                 combined with --no-direct-rays"
                    .into(),
            );
        }
        Ok(())
    }
}

/// How renders are shaded.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ShadingArg {
    /// Vertex radiosity interpolated across each patch.
    Smooth,
    /// One colour per patch.
    Flat,
}

/// Parses `WxH`.
fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("'{s}' is not WIDTHxHEIGHT"))?;
    let side = |v: &str| match v.trim().parse::<u32>() {
        Ok(n) if (1..=16384).contains(&n) => Ok(n),
        _ => Err(format!("'{v}' is not a side of 1 to 16384 pixels")),
    };
    Ok((side(w)?, side(h)?))
}

/// Parses `auto` or a number of stops.
fn parse_exposure(s: &str) -> Result<Exposure, String> {
    if s.eq_ignore_ascii_case("auto") {
        return Ok(Exposure::Auto);
    }
    match s.parse::<f32>() {
        Ok(stops) if stops.is_finite() && stops.abs() <= 64.0 => Ok(Exposure::Stops(stops)),
        _ => Err(format!(
            "'{s}' is neither 'auto' nor a number of stops in [-64, 64]"
        )),
    }
}

/// `--gather-rays`: a count of final-gather rays per sample, or `None` for `auto`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GatherRays(pub Option<u32>);

/// Parses `--gather-rays`: `auto` or a count of rays per sample, 0 to 256.
fn parse_gather(s: &str) -> Result<GatherRays, String> {
    if s.eq_ignore_ascii_case("auto") {
        return Ok(GatherRays(None));
    }
    match s.parse::<u32>() {
        Ok(n) if n <= 256 => Ok(GatherRays(Some(n))),
        _ => Err(format!(
            "'{s}' is neither 'auto' nor a count of rays from 0 to 256"
        )),
    }
}

/// Parses a positive number of seconds.
fn parse_seconds(s: &str) -> Result<f64, String> {
    match s.parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        _ => Err(format!("'{s}' is not a positive number of seconds")),
    }
}

/// A positive finite number (a relative error such as 0.02).
fn parse_fraction(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        _ => Err(format!("'{s}' is not a positive finite number")),
    }
}

/// Parses `--sun X,Y,Z,E[,DIAM]` ([`mcrad_scene_io::Sun`]'s `FromStr`).
fn parse_sun(s: &str) -> Result<mcrad_scene_io::Light, String> {
    s.parse().map(mcrad_scene_io::Light::Sun)
}

/// Parses `--sky R,G,B`: a radiance per channel, each finite and `>= 0` W/(m² sr).
fn parse_sky(s: &str) -> Result<glam::DVec3, String> {
    match s.parse::<mcrad_scene_io::Sky>()? {
        mcrad_scene_io::Sky::Uniform(radiance) => Ok(radiance),
        mcrad_scene_io::Sky::Map(_) => Err(format!("'{s}' is not R,G,B")),
    }
}

/// Parses a finite angle in degrees (`--sky-rotate`).
fn parse_degrees(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(x) if x.is_finite() => Ok(x),
        _ => Err(format!("'{s}' is not a finite angle in degrees")),
    }
}

/// Parses a positive finite length (`--max-edge`, `--min-edge`).
fn parse_length(s: &str) -> Result<f32, String> {
    match s.parse::<f32>() {
        Ok(x) if x.is_finite() && x > 0.0 => Ok(x),
        _ => Err(format!(
            "'{s}' is not a positive finite length in scene units"
        )),
    }
}

/// Parses a count written as an integer (`2000000`) or in float notation (`2e6`), at least 1
/// and at most `u64::MAX`; each way to miss says which.
/// A byte count: a whole number (`4000000000`, `4e9`) or one with a binary suffix `K`, `M`,
/// `G` or `T` (`4G` = 4 GiB, `1.5G`), at least 1.
fn parse_bytes(s: &str) -> Result<u64, String> {
    let t = s.trim();
    let (number, scale) = match t.char_indices().last() {
        Some((i, c)) if c.is_ascii_alphabetic() && !t.ends_with(['e', 'E']) => {
            let scale: u64 = match c.to_ascii_uppercase() {
                'K' => 1 << 10,
                'M' => 1 << 20,
                'G' => 1 << 30,
                'T' => 1 << 40,
                _ => return Err(format!("'{s}': the suffix may be K, M, G or T (binary)")),
            };
            (&t[..i], scale)
        }
        _ => (t, 1),
    };
    let x: f64 = number
        .parse()
        .map_err(|_| format!("'{s}' is not a number of bytes"))?;
    let bytes = x * scale as f64;
    if !bytes.is_finite() || bytes < 1.0 || bytes >= u64::MAX as f64 {
        return Err(format!(
            "'{s}' is not a number of bytes from 1 to about 1.8e19"
        ));
    }
    Ok(bytes.round() as u64)
}

/// The default of `--max-memory`: the machine's RAM (`MemTotal` of `/proc/meminfo`) less a
/// tenth, and at least 256 MiB less; `None` (no limit) where it cannot be read.
fn default_max_memory() -> Option<u64> {
    let info = std::fs::read_to_string("/proc/meminfo").ok()?;
    let total_kib: u64 = info
        .lines()
        .find_map(|l| l.strip_prefix("MemTotal:"))?
        .trim()
        .trim_end_matches("kB")
        .trim()
        .parse()
        .ok()?;
    let total = total_kib.saturating_mul(1024);
    Some(total.saturating_sub((total / 10).max(256 << 20)).max(1))
}

fn parse_count(s: &str) -> Result<u64, String> {
    if let Ok(n) = s.parse::<u64>() {
        return if n >= 1 {
            Ok(n)
        } else {
            Err("must be at least 1".into())
        };
    }
    let x: f64 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    if x.is_nan() {
        return Err(format!("'{s}' is not a number"));
    }
    if x < 1.0 {
        return Err(format!("'{s}' is less than 1"));
    }
    // (u64::MAX as f64 is 2^64, one past the largest count)
    if x >= u64::MAX as f64 {
        return Err(format!(
            "'{s}' is too large: at most {} (about 1.8e19)",
            u64::MAX
        ));
    }
    if x.fract() != 0.0 {
        return Err(format!("'{s}' is not a whole number"));
    }
    Ok(x as u64)
}

#[cfg(test)]
mod tests {
    use super::{Args, Command, Solve, parse_count, parse_exposure, parse_size};
    use clap::Parser;
    use mcrad_mc_radiosity::Method;
    use mcrad_render::Exposure;
    use mcrad_solve::{Budget, MeshPlan, Settings};

    fn solve(args: &[&str]) -> Solve {
        let argv = ["mcrad", "solve", "scene.obj"].iter().chain(args);
        match Args::try_parse_from(argv).unwrap().command {
            Command::Solve(s) => s,
            Command::Merge(_) | Command::Bake(_) => unreachable!("a solve command line"),
        }
    }

    #[test]
    fn the_command_line_defaults_are_the_library_defaults() {
        let s = solve(&[]);
        assert_eq!(s.settings(), Settings::default());
        assert_eq!(s.method(), Method::default());
        let now = std::time::Instant::now();
        let budget = s.budget(now);
        assert_eq!(budget.total_rays(), Budget::default().total_rays());
        assert_eq!(solve(&["--time", "5"]).budget(now).total_rays(), u64::MAX);
        let render = mcrad_render::RenderSettings::default();
        assert_eq!(
            (s.size, s.spp),
            ((render.width, render.height), render.samples_per_pixel)
        );
    }

    #[test]
    fn a_continued_run_takes_the_saved_settings_but_what_is_given() {
        let saved = Settings {
            seed: 9,
            method: Method::Prr,
            ..Settings::default()
        };
        let mut s = solve(&["--seed", "4", "--ambient"]);
        s.given = vec!["seed".into()];
        let over = s.settings_over(saved, false);
        assert_eq!(
            (over.seed, over.method, over.ambient),
            (4, Method::Prr, false)
        );
        // one mesh bound given again keeps the other saved ones
        let saved = Settings {
            mesh: MeshPlan::Adaptive {
                max_patches: Some(8000),
                min_edge: Some(0.01),
            },
            method: Method::TwoPass,
            ..Settings::default()
        };
        let mut s = solve(&["--min-edge", "0.01", "--split"]);
        s.given = vec!["min_edge".into(), "split".into()];
        let over = s.settings_over(saved, false);
        assert_eq!(over.mesh, saved.mesh);
        assert_eq!(
            over.method,
            Method::TwoPassSplit,
            "--split applies to the saved method"
        );
        let mut s = solve(&["--mesh", "adaptive"]);
        s.given = vec!["mesh".into()];
        assert_eq!(s.settings_over(saved, false).mesh, saved.mesh);
        let mut s = solve(&["--max-edge", "0.2"]);
        s.given = vec!["max_edge".into()];
        assert_eq!(
            s.settings_over(saved, false).mesh,
            MeshPlan::Uniform {
                max_edge: Some(0.2)
            }
        );
    }

    #[test]
    fn every_registered_method_parses_and_split_is_an_alias() {
        for m in Method::ALL {
            assert_eq!(solve(&["--method", m.name()]).method(), m);
        }
        let split = solve(&["--method", "two-pass", "--split"]);
        assert_eq!(split.method(), Method::TwoPassSplit);
        // As before the registry: other methods ignore --split.
        assert_eq!(solve(&["--method", "prr", "--split"]).method(), Method::Prr);
        assert!(Args::try_parse_from(["mcrad", "solve", "s.obj", "--method", "teleport"]).is_err());
    }

    #[test]
    fn sizes_and_exposures_parse() {
        assert_eq!(parse_size("640x480"), Ok((640, 480)));
        assert!(
            parse_size("0x10").is_err()
                && parse_size("10").is_err()
                && parse_size("20000x10").is_err()
        );
        assert_eq!(parse_exposure("auto"), Ok(Exposure::Auto));
        assert_eq!(parse_exposure("-1.5"), Ok(Exposure::Stops(-1.5)));
        assert!(parse_exposure("bright").is_err() && parse_exposure("inf").is_err());
    }

    #[test]
    fn counts_accept_integers_and_float_notation() {
        assert_eq!(parse_count("2000000"), Ok(2_000_000));
        assert_eq!(parse_count("2e6"), Ok(2_000_000));
        assert_eq!(parse_count("1.5e3"), Ok(1500));
        for bad in ["0", "-5", "1.5", "abc", "nan", "inf", "1e30"] {
            assert!(parse_count(bad).is_err(), "{bad}");
        }
        // each miss is called what it is
        assert_eq!(
            parse_count("1e30").unwrap_err(),
            "'1e30' is too large: at most 18446744073709551615 (about 1.8e19)"
        );
        assert!(parse_count("inf").unwrap_err().contains("too large"));
        assert_eq!(
            parse_count("1.5").unwrap_err(),
            "'1.5' is not a whole number"
        );
        assert_eq!(parse_count("-5").unwrap_err(), "'-5' is less than 1");
        assert_eq!(parse_count("1.8e19"), Ok(18_000_000_000_000_000_000));
    }

    #[test]
    fn lengths_and_thread_counts_are_checked_when_parsed() {
        assert_eq!(super::parse_length("0.5"), Ok(0.5));
        for bad in ["0", "-1", "inf", "nan", "1e39", "x"] {
            assert!(super::parse_length(bad).is_err(), "{bad}");
        }
        let parse = |t: &str| Args::try_parse_from(["mcrad", "solve", "s.obj", "--threads", t]);
        assert!(parse("256").is_ok());
        assert!(parse("257").is_err() && parse("1000").is_err() && parse("0").is_err());
    }
}
