//! `cargo xtask experiment meshing` (issue 15, item 5): image error and per-face `rms_rel`
//! against time, uniform meshes of several sizes against adaptive meshing, judged against an
//! independent ground truth.
//!
//! Per scene: the ground-truth picture by the path tracer (`mcrad_lab::pathtrace`, cached in
//! `target/meshing/`), the per-face reference (the area-weighted face means of a long run on a
//! fine uniform mesh, cached too), then `mcrad solve` with `--time T` for every mesh setting
//! and time; each run's picture is scored by `image_error_against_noisy` (the ground truth's
//! own noise subtracted) and its `--per-face` CSV by `rms_rel` against the per-face reference.
//! Writes `docs/meshing-experiment.md`, a CSV of the points and one plot per scene.

use anyhow::{Context, Result, bail};
use mcrad_lab::plot::{PlotSpec, Series, line_plot};
use mcrad_meshing::{Mesh, Subdivision};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

/// Rays per pixel of every solver picture (`mcrad solve --spp`): at the default 16, the
/// pixels along silhouettes and contact lines measured a floor of about 1.1% on the Cornell box
/// that no mesh lowers (a uniform mesh of 78,000 elements: 1.08% at 16, 0.79% at 256), which
/// would hide the meshes' differences.
const RENDER_SPP: u32 = 256;

/// One scene of the experiment.
struct ExpScene {
    name: &'static str,
    file: &'static str,
    what: &'static str,
    camera: &'static str,
    size: (u32, u32),
    /// Uniform `--max-edge` values compared (besides the default).
    uniform: &'static [f32],
    /// The fine uniform mesh and rays of the per-face reference.
    reference: (f32, &'static str),
    /// Uniform `--max-edge` values of the patches-against-error curve, coarse to fine.
    curve_edges: &'static [f32],
}

/// `--max-patches` values of the adaptive patches-against-error curve (the start takes at most
/// half of it).
const CURVE_BUDGETS: [usize; 4] = [4_000, 8_000, 16_000, mcrad_meshing::DEFAULT_MAX_PATCHES];

const SCENES: [ExpScene; 3] = [
    ExpScene {
        name: "cornell",
        file: "scenes/cornell-box.obj",
        what: "the Cornell box with its two blocks",
        camera: "eye=0.278,0.273,-0.8,look=0.278,0.273,0,fov=39.3",
        size: (256, 256),
        uniform: &[0.02, 0.01],
        reference: (0.01, "1e8"),
        curve_edges: &[0.04, 0.02, 0.014, 0.01, 0.007, 0.005, 0.0035],
    },
    ExpScene {
        name: "table-room",
        file: "scenes/table-room.obj",
        what: "a 5 x 2.6 x 4 m room of one quad per wall, a table, a cabinet and a 0.4 m light",
        camera: "eye=4.8,1.8,3.9,look=1.6,0.4,0.8,fov=65",
        size: (320, 240),
        uniform: &[0.15, 0.07],
        reference: (0.05, "1e8"),
        curve_edges: &[0.345, 0.15, 0.1, 0.07, 0.05, 0.035],
    },
    ExpScene {
        name: "boxes-room",
        file: "scenes/boxes-room.obj",
        what: "a 5 x 2.6 x 4 m room of boxes (cargo xtask gen-scenes)",
        camera: "eye=4.8,2.2,3.9,look=1.5,0.3,0.8,fov=65",
        size: (320, 240),
        uniform: &[0.15, 0.07],
        reference: (0.05, "1e8"),
        curve_edges: &[0.15, 0.1, 0.07, 0.05, 0.035],
    },
];

/// The experiment's settings.
struct Options {
    scenes: Vec<&'static ExpScene>,
    times: Vec<f64>,
    spp: u32,
    /// Rays of every run of the patches-against-error curve (0: no curve).
    curve_rays: u64,
    out: PathBuf,
}

/// The arguments of `cargo xtask experiment meshing`.
#[derive(Debug, Default, clap::Args)]
pub struct MeshingArgs {
    /// A smoke run: 1 s, 16 paths per pixel, 2e6 rays per curve point
    #[arg(long)]
    pub quick: bool,
    /// Scenes, comma-separated (cornell, table-room, boxes-room) [default: all]
    #[arg(long, value_name = "a,b", value_delimiter = ',')]
    pub scenes: Vec<String>,
    /// `mcrad solve --time` values, comma-separated [default: 2.5,5,10; 1 with --quick]
    #[arg(long, value_name = "2.5,5,10", value_delimiter = ',')]
    pub times: Vec<f64>,
    /// Paths per pixel of the ground truth [default: 1024, 16 with --quick]
    #[arg(long, value_name = "N")]
    pub spp: Option<u32>,
    /// Rays of every run of the patches-against-error curve, 0: no curve [default: 1e8, 2e6
    /// with --quick]
    #[arg(long, value_name = "N", value_parser = crate::parse_count)]
    pub curve_rays: Option<u64>,
    /// Output directory, relative to the workspace [default: docs]
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

impl Options {
    fn parse(root: &Path, args: &MeshingArgs) -> Result<Options> {
        let quick = args.quick;
        let scenes = if args.scenes.is_empty() {
            SCENES.iter().collect()
        } else {
            args.scenes
                .iter()
                .map(|n| {
                    SCENES
                        .iter()
                        .find(|s| s.name == n)
                        .with_context(|| format!("unknown scene '{n}'"))
                })
                .collect::<Result<_>>()?
        };
        Ok(Options {
            scenes,
            times: if !args.times.is_empty() {
                args.times.clone()
            } else if quick {
                vec![1.0]
            } else {
                vec![2.5, 5.0, 10.0]
            },
            spp: args.spp.unwrap_or(if quick { 16 } else { 1024 }),
            curve_rays: args
                .curve_rays
                .unwrap_or(if quick { 2_000_000 } else { 100_000_000 }),
            out: root.join(args.out.as_deref().unwrap_or(Path::new("docs"))),
        })
    }
}

/// One measured run.
struct Point {
    mesh: String,
    seconds_asked: f64,
    patches: u64,
    rays: u64,
    image: f64,
    dark_third: f64,
    per_face: f64,
}

impl Point {
    /// Its errors as three Markdown table cells: image error, dark third, per-face rms_rel.
    fn error_cells(&self) -> String {
        format!(
            "{:.2}% | {:.2}% | {:.2}%",
            100.0 * self.image,
            100.0 * self.dark_third,
            100.0 * self.per_face
        )
    }
}

/// Runs the experiment (see the module documentation).
pub fn run(root: &Path, mcrad: &Path, args: &MeshingArgs) -> Result<()> {
    let options = Options::parse(root, args)?;
    let work = super::target_dir().join("meshing");
    std::fs::create_dir_all(&work)?;
    std::fs::create_dir_all(&options.out)?;
    let mut md = String::new();
    let mut csv = String::from("scene,mesh,seconds,patches,rays,img_rel,dark_third,face_rms_rel\n");
    let _ = write!(
        md,
        "# Adaptive against uniform meshes, against an independent ground truth\n\n\
         *Generated by `cargo xtask experiment meshing` (xtask/src/meshing_exp.rs); rerun it \
         rather than editing this file.*\n\n\
         Per scene: `mcrad solve SCENE --time T` (method `combined`, seed 0, all cores) with the \
         default uniform mesh, finer uniform meshes (`--max-edge`) and `--mesh adaptive`; \
         **image error**: the render (`--camera`, `--spp {}`: at the default 16 the pixels \
         along silhouettes and contact lines leave a floor no mesh lowers) against a path-traced \
         picture of {} paths per pixel (`cargo xtask path-trace`), its own noise subtracted \
         (`image-error --reference-error`), over the pixels that see no emitter, and over the \
         darkest third of them; **per-face rms_rel**: the `--per-face` means against those of a \
         long run on a fine uniform mesh (issue 15's measure of the per-face average). Times \
         are wall-clock on this machine, from the start of loading (`--time`).\n",
        RENDER_SPP, options.spp
    );
    for scene in &options.scenes {
        eprintln!("meshing experiment: {}", scene.name);
        let truth = ground_truth(root, &work, scene, options.spp)?;
        let reference = face_reference(root, mcrad, &work, scene)?;
        let mut meshes: Vec<(String, Vec<String>)> = vec![(
            "uniform default".into(),
            vec!["--mesh".into(), "uniform".into()],
        )];
        for e in scene.uniform {
            meshes.push((
                format!("uniform {e}"),
                vec!["--max-edge".into(), e.to_string()],
            ));
        }
        meshes.push(("adaptive".into(), vec!["--mesh".into(), "adaptive".into()]));
        let mut points = Vec::new();
        for (label, extra) in &meshes {
            for &t in &options.times {
                let p = measure(
                    root,
                    mcrad,
                    &work,
                    scene,
                    label,
                    extra,
                    Budget::Seconds(t),
                    &truth,
                    &reference,
                )?;
                let _ = writeln!(
                    csv,
                    "{},{},{},{},{},{:.6},{:.6},{:.6}",
                    scene.name, p.mesh, t, p.patches, p.rays, p.image, p.dark_third, p.per_face
                );
                points.push(p);
            }
        }
        let _ = write!(
            md,
            "\n## {} ({})\n\nCamera `{}`, {} x {} pixels; per-face reference: `--max-edge {}`, \
             {} rays.\n\n![{}: image error against seconds](meshing-experiment-{}.png)\n\n\
             | mesh | `--time` (s) | patches | rays | image error | dark third | per-face rms_rel |\n\
             |---|---:|---:|---:|---:|---:|---:|\n",
            scene.name,
            scene.what,
            scene.camera,
            scene.size.0,
            scene.size.1,
            scene.reference.0,
            scene.reference.1,
            scene.name,
            scene.name
        );
        for p in &points {
            let _ = writeln!(
                md,
                "| {} | {} | {} | {:.2e} | {} |",
                p.mesh,
                p.seconds_asked,
                p.patches,
                p.rays as f64,
                p.error_cells()
            );
        }
        let series = meshes
            .iter()
            .map(|(label, _)| Series {
                name: label.clone(),
                points: points
                    .iter()
                    .filter(|p| &p.mesh == label && p.image > 0.0)
                    .map(|p| (p.seconds_asked, 100.0 * p.image))
                    .collect(),
                band: None,
            })
            .collect();
        line_plot(
            &options
                .out
                .join(format!("meshing-experiment-{}.png", scene.name)),
            &PlotSpec {
                title: format!("{}: image error against time", scene.name),
                x_label: "--time (s)".into(),
                y_label: "image error (%)".into(),
                log_x: true,
                log_y: true,
                series,
            },
        )?;
        if options.curve_rays > 0 {
            let curve = patches_curve(
                root,
                mcrad,
                &work,
                scene,
                options.curve_rays,
                &truth,
                &reference,
                &options.out,
            )?;
            md.push_str(&curve.markdown);
            csv.push_str(&curve.csv);
        }
    }
    std::fs::write(options.out.join("meshing-experiment.md"), md)?;
    std::fs::write(options.out.join("meshing-experiment.csv"), csv)?;
    eprintln!(
        "wrote {}",
        options.out.join("meshing-experiment.md").display()
    );
    Ok(())
}

/// The path-traced picture and its standard error, rendered once per `spp` and cached.
fn ground_truth(
    root: &Path,
    work: &Path,
    scene: &ExpScene,
    spp: u32,
) -> Result<(mcrad_render::Image, mcrad_render::Image)> {
    let picture = work.join(format!("{}-truth-{spp}.exr", scene.name));
    let error = work.join(format!("{}-truth-{spp}.error.exr", scene.name));
    if !(picture.is_file() && error.is_file()) {
        super::path_trace::run_path_trace(&super::path_trace::PathTraceArgs {
            scene: root.join(scene.file),
            camera: mcrad_render::parse_camera(scene.camera)?,
            size: scene.size,
            spp,
            seed: 0,
            out: picture.clone(),
            error: Some(error.clone()),
            sun: None,
            sky: None,
        })?;
    }
    Ok((
        mcrad_render::read_exr(&picture)?,
        mcrad_render::read_exr(&error)?,
    ))
}

/// The per-face reference: face means (W/m²) of a long run on a fine uniform mesh, with each
/// face's area and emission, in face order; cached.
fn face_reference(root: &Path, mcrad: &Path, work: &Path, scene: &ExpScene) -> Result<FaceValues> {
    let (edge, rays) = scene.reference;
    let csv = work.join(format!("{}-faces-{edge}-{rays}.csv", scene.name));
    if !csv.is_file() {
        solve(
            mcrad,
            &root.join(scene.file),
            &[
                "--max-edge".into(),
                edge.to_string(),
                "--rays".into(),
                rays.into(),
                "--patches".into(),
                csv.display().to_string(),
                "--per-face".into(),
            ],
        )?;
    }
    face_values(root, scene, &csv)
}

/// Face means of a `--per-face` CSV with each face's area and emission.
struct FaceValues {
    area: Vec<f64>,
    emission: Vec<glam::DVec3>,
    values: Vec<glam::DVec3>,
}

fn face_values(root: &Path, scene: &ExpScene, csv: &Path) -> Result<FaceValues> {
    let rows = mcrad_export::read_patch_csv(csv)?;
    let loaded = mcrad_scene_io::load(&root.join(scene.file))?;
    let faces = Mesh::build(&loaded.scene, Subdivision::None)?;
    let mut emission = vec![glam::DVec3::ZERO; rows.len()];
    for p in faces.patches() {
        if let Some(e) = emission.get_mut(p.face as usize) {
            *e = p.emission.as_dvec3();
        }
    }
    if rows.iter().enumerate().any(|(k, r)| r.patch as usize != k) {
        bail!("{}: the faces are not numbered in order", csv.display());
    }
    Ok(FaceValues {
        area: rows.iter().map(|r| r.area).collect(),
        emission,
        values: rows.iter().map(|r| r.radiosity).collect(),
    })
}

/// Runs `mcrad solve SCENE ARGS -q`.
fn solve(mcrad: &Path, scene: &Path, args: &[String]) -> Result<()> {
    let status = Command::new(mcrad)
        .arg("solve")
        .arg(scene)
        .args(args)
        .arg("-q")
        .status()
        .context("could not run mcrad")?;
    if !status.success() {
        bail!("mcrad solve {} {} failed", scene.display(), args.join(" "));
    }
    Ok(())
}

/// What a run may spend.
#[derive(Clone, Copy)]
enum Budget {
    /// `--time` seconds.
    Seconds(f64),
    /// `--rays`.
    Rays(u64),
}

/// One run: `mcrad solve` with `extra` and the budget, scored.
#[allow(clippy::too_many_arguments)]
fn measure(
    root: &Path,
    mcrad: &Path,
    work: &Path,
    scene: &ExpScene,
    label: &str,
    extra: &[String],
    budget: Budget,
    truth: &(mcrad_render::Image, mcrad_render::Image),
    reference: &FaceValues,
) -> Result<Point> {
    let (option, amount, seconds) = match budget {
        Budget::Seconds(t) => ("--time", t.to_string(), t),
        Budget::Rays(r) => ("--rays", r.to_string(), 0.0),
    };
    // Not `with_extension`: the stem has dots of its own (`uniform-0.07-2.5`).
    let stem = format!(
        "{}-{}-{}{amount}",
        scene.name,
        label.replace(' ', "-"),
        if seconds > 0.0 { "" } else { "r" }
    );
    let (image, faces, stats) = (
        work.join(format!("{stem}.exr")),
        work.join(format!("{stem}.csv")),
        work.join(format!("{stem}.json")),
    );
    let mut args = extra.to_vec();
    for a in [
        option.to_string(),
        amount,
        "--camera".into(),
        scene.camera.into(),
        "--size".into(),
        format!("{}x{}", scene.size.0, scene.size.1),
        "--spp".into(),
        RENDER_SPP.to_string(),
        "--image".into(),
        image.display().to_string(),
        "--patches".into(),
        faces.display().to_string(),
        "--per-face".into(),
        "--stats".into(),
        stats.display().to_string(),
    ] {
        args.push(a);
    }
    solve(mcrad, &root.join(scene.file), &args)?;
    let picture = mcrad_render::read_exr(&image)?;
    let e = mcrad_lab::compare::image_error_against_noisy(
        &picture,
        &truth.0,
        Some(&truth.1),
        mcrad_lab::compare::EMITTER_FRACTION,
    )?;
    let run = face_values(root, scene, &faces)?;
    if run.values.len() != reference.values.len() {
        bail!(
            "{}: {} faces, the reference has {}",
            faces.display(),
            run.values.len(),
            reference.values.len()
        );
    }
    let per_face = mcrad_combine::rms_rel(
        &reference.area,
        &reference.emission,
        &run.values,
        &reference.values,
    );
    let stats: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&stats)?)?;
    let number = |k: &str| stats[k].as_u64().unwrap_or(0);
    let point = Point {
        mesh: label.to_string(),
        seconds_asked: seconds,
        patches: number("patches"),
        rays: number("rays"),
        image: e.relative,
        dark_third: e.dark_third,
        per_face,
    };
    eprintln!(
        "  {label}, {option} {}: {} patches, image error {:.2}%, per-face {:.2}%",
        match budget {
            Budget::Seconds(t) => t.to_string(),
            Budget::Rays(r) => format!("{r:.1e}"),
        },
        point.patches,
        100.0 * point.image,
        100.0 * point.per_face
    );
    Ok(point)
}

/// The patches-against-error section of one scene: its markdown and CSV rows.
struct Curve {
    markdown: String,
    csv: String,
}

/// Uniform meshes of `scene.curve_edges` and adaptive meshes of [`CURVE_BUDGETS`], each
/// solved with `rays`, scored; for each adaptive mesh the patches a uniform mesh needs for the
/// same image error ([`uniform_patches_at`]); a table and a plot (`meshing-curve-NAME.png`).
#[allow(clippy::too_many_arguments)]
fn patches_curve(
    root: &Path,
    mcrad: &Path,
    work: &Path,
    scene: &ExpScene,
    rays: u64,
    truth: &(mcrad_render::Image, mcrad_render::Image),
    reference: &FaceValues,
    out: &Path,
) -> Result<Curve> {
    let run = |label: String, extra: Vec<String>| {
        measure(
            root,
            mcrad,
            work,
            scene,
            &label,
            &extra,
            Budget::Rays(rays),
            truth,
            reference,
        )
    };
    let mut uniform = Vec::new();
    for e in scene.curve_edges {
        uniform.push(run(
            format!("uniform {e}"),
            vec!["--max-edge".into(), e.to_string()],
        )?);
    }
    let mut adaptive = Vec::new();
    for b in CURVE_BUDGETS {
        adaptive.push(run(
            format!("adaptive {b}"),
            vec!["--max-patches".into(), b.to_string()],
        )?);
    }
    let mut csv = String::new();
    for p in uniform.iter().chain(&adaptive) {
        let _ = writeln!(
            csv,
            "{},{},,{},{},{:.6},{:.6},{:.6}",
            scene.name, p.mesh, p.patches, p.rays, p.image, p.dark_third, p.per_face
        );
    }
    let curve: Vec<(f64, f64)> = uniform
        .iter()
        .map(|p| (p.patches as f64, p.image))
        .collect();
    let mut md = String::new();
    let _ = write!(
        md,
        "\n### {}: patches against image error, {:.0e} rays each\n\n\
         ![{}: image error against patches](meshing-curve-{}.png)\n\n\
         *Uniform patches at this error*: interpolated in log-log between the two uniform meshes \
         whose errors bracket the adaptive run's; *none (best: N)* when no uniform mesh reaches \
         it at these rays, N the patches of the uniform mesh of the lowest error (its ratio is a \
         lower bound).\n\n\
         | mesh | patches | image error | dark third | per-face rms_rel | uniform patches at \
         this error | ratio |\n|---|---:|---:|---:|---:|---:|---:|\n",
        scene.name, rays as f64, scene.name, scene.name
    );
    for p in &uniform {
        let _ = writeln!(
            md,
            "| {} | {} | {} | | |",
            p.mesh,
            p.patches,
            p.error_cells()
        );
    }
    for p in &adaptive {
        let (equal, ratio) = match uniform_patches_at(&curve, p.image) {
            Equal::At(n) => (format!("{n:.0}"), format!("{:.1}x", n / p.patches as f64)),
            Equal::BelowEvery(n) => (
                format!("none (best: {n:.0})"),
                format!("> {:.1}x", n / p.patches as f64),
            ),
            Equal::BeyondCoarsest(n) => (
                format!("< {n:.0}"),
                format!("< {:.1}x", n / p.patches as f64),
            ),
        };
        let _ = writeln!(
            md,
            "| **{}** | {} | {} | {equal} | **{ratio}** |",
            p.mesh,
            p.patches,
            p.error_cells()
        );
    }
    let series = [("uniform", &uniform), ("adaptive", &adaptive)]
        .into_iter()
        .map(|(name, points)| Series {
            name: name.into(),
            points: points
                .iter()
                .filter(|p| p.image > 0.0)
                .map(|p| (p.patches as f64, 100.0 * p.image))
                .collect(),
            band: None,
        })
        .collect();
    line_plot(
        &out.join(format!("meshing-curve-{}.png", scene.name)),
        &PlotSpec {
            title: format!(
                "{}: image error against patches, {rays:.0e} rays",
                scene.name
            ),
            x_label: "patches".into(),
            y_label: "image error (%)".into(),
            log_x: true,
            log_y: true,
            series,
        },
    )?;
    Ok(Curve { markdown: md, csv })
}

/// The patches a uniform mesh needs for an image error, from a measured curve.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Equal {
    /// Interpolated between two measured meshes.
    At(f64),
    /// Lower than every measured uniform mesh's error: the patches of the one of the lowest
    /// error (at a fixed ray budget the finest is not it: its rays per patch are fewest).
    BelowEvery(f64),
    /// Higher than every measured one's: fewer than the coarsest one's patches.
    BeyondCoarsest(f64),
}

/// The patches of a uniform mesh of image error `error`, interpolated linearly in
/// `(log patches, log error)` between the first pair of consecutive points of `curve`
/// (`(patches, error)`, coarse to fine) whose errors bracket it.
fn uniform_patches_at(curve: &[(f64, f64)], error: f64) -> Equal {
    for w in curve.windows(2) {
        let ((n1, e1), (n2, e2)) = (w[0], w[1]);
        if e1 >= error && error >= e2 && e1 > e2 {
            let t = (e1 / error).ln() / (e1 / e2).ln();
            return Equal::At(n1 * (n2 / n1).powf(t));
        }
    }
    if curve.iter().all(|&(_, e)| error < e) {
        let best = curve
            .iter()
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .map_or(0.0, |c| c.0);
        Equal::BelowEvery(best)
    } else {
        Equal::BeyondCoarsest(curve.iter().map(|c| c.0).fold(f64::INFINITY, f64::min))
    }
}

#[cfg(test)]
mod tests {
    use super::{Equal, uniform_patches_at};

    #[test]
    fn equal_error_patches_interpolate_in_log_log() {
        // error = 10 / sqrt(patches): 100 -> 1, 400 -> 0.5, 1600 -> 0.25.
        let curve = [(100.0, 1.0), (400.0, 0.5), (1600.0, 0.25)];
        let Equal::At(n) = uniform_patches_at(&curve, 10.0 / 800f64.sqrt()) else {
            panic!("bracketed")
        };
        assert!((n - 800.0).abs() < 1e-9, "{n}");
        assert_eq!(uniform_patches_at(&curve, 0.1), Equal::BelowEvery(1600.0));
        // A curve that turns up again (too few rays per patch on the finest mesh).
        let turning = [(100.0, 1.0), (400.0, 0.5), (1600.0, 0.6)];
        assert_eq!(uniform_patches_at(&turning, 0.4), Equal::BelowEvery(400.0));
        assert_eq!(
            uniform_patches_at(&curve, 2.0),
            Equal::BeyondCoarsest(100.0)
        );
    }
}
