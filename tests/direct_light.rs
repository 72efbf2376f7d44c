//! The lights' direct light drawn per pixel sample in renders (the default with punctual lights
//! or a sun), against `--no-direct-rays` (the solution's per-vertex interpolation).

use mcrad_render::{parse_camera, read_exr};
use std::path::Path;
use std::process::{Command, Output};

fn mcrad(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_mcrad"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("mcrad runs")
}

fn path(dir: &Path, name: &str) -> String {
    dir.join(name).to_string_lossy().into_owned()
}

/// A 10 m floor (reflectance 0.5) and a black wall 1 m high along `x = 0`; a delta sun at 45
/// degrees elevation from `-x`, 1000 W/m². Nothing reflects onto the floor (the wall is black,
/// the floor flat), so the exact radiance is `rho E sin(45°) / pi = 112.54 W/(m² sr)` where the
/// sun reaches the floor and 0 in the wall's shadow, `0 < x < 1`.
const FLOOR_WALL_OBJ: &str = "mtllib s.mtl
v -4.7 0 -5
v -4.7 0 5
v 5.3 0 5
v 5.3 0 -5
v 0 0 -5
v 0 0 5
v 0 1 5
v 0 1 -5
usemtl floor
f 1 2 3 4
usemtl wall
f 5 6 7 8
";

const FLOOR_WALL_MTL: &str = "newmtl floor\nKd 0.5 0.5 0.5\nnewmtl wall\nKd 0 0 0\n";

const CAMERA: &str = "eye=1,3,1.5,look=1,0,0,fov=40";
const SIZE: u32 = 96;

/// The floor's `x` seen through pixel `(px, py)`'s centre (the camera's ray met with `y = 0`).
fn floor_x(px: u32, py: u32) -> Option<f32> {
    let camera = parse_camera(CAMERA).unwrap();
    let ray = camera.ray(
        glam::Vec2::new(px as f32 + 0.5, py as f32 + 0.5),
        SIZE,
        SIZE,
    );
    (ray.dir.y < 0.0).then(|| ray.origin.x + ray.dir.x * (-ray.origin.y / ray.dir.y))
}

/// Renders the floor and wall under the sun (uniform 0.5 m patches, their edges off the shadow's
/// edge at `x = 1`) and returns, for the pixels whose centre sees the floor within 3 to 12 cm
/// of the shadow's edge (a pixel spans about 3 cm there), `(x, radiance, exact)`.
fn edge_pixels(extra: &[&str]) -> Vec<(f32, f32, f32)> {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("s.obj"), FLOOR_WALL_OBJ).unwrap();
    std::fs::write(dir.path().join("s.mtl"), FLOOR_WALL_MTL).unwrap();
    let image = path(dir.path(), "i.exr");
    let size = format!("{SIZE}x{SIZE}");
    let mut args = vec![
        "solve",
        &*path(dir.path(), "s.obj"),
        "-q",
        "--rays",
        "2e5",
        "--mesh",
        "uniform",
        "--max-edge",
        "0.5",
        "--sun=-1,1,0,1000,0",
        "--camera",
        CAMERA,
        "--size",
        &size,
        "--image",
        &image,
    ]
    .into_iter()
    .map(str::to_string)
    .collect::<Vec<_>>();
    args.extend(extra.iter().map(|s| s.to_string()));
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = mcrad(&args);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let picture = read_exr(Path::new(&image)).unwrap();
    let lit = (0.5 * 1000.0 * std::f64::consts::FRAC_1_SQRT_2 / std::f64::consts::PI) as f32;
    let mut out = Vec::new();
    for py in 0..SIZE {
        for px in 0..SIZE {
            let Some(x) = floor_x(px, py) else { continue };
            let d = (x - 1.0).abs();
            if (0.03..0.12).contains(&d) {
                let exact = if x > 1.0 { lit } else { 0.0 };
                out.push((x, picture.get(px, py).unwrap().y, exact));
            }
        }
    }
    out
}

/// With the direct light drawn per pixel (the default), every pixel 3 to 12 cm from the
/// shadow's edge is within 1% of the lit radiance (exact: a delta sun, no indirect light) on
/// the lit side and black on the other; the solution's interpolation (`--no-direct-rays`)
/// smears the edge over its 0.5 m patches and misses by more than 20% on some of them.
#[test]
fn a_sun_shadow_edge_is_sharp_in_renders() {
    let lit = (0.5 * 1000.0 * std::f64::consts::FRAC_1_SQRT_2 / std::f64::consts::PI) as f32;
    let sharp = edge_pixels(&[]);
    assert!(sharp.len() > 100, "{} pixels near the edge", sharp.len());
    for &(x, l, exact) in &sharp {
        assert!((l - exact).abs() <= 0.01 * lit, "x = {x}: {l} vs {exact}");
    }
    let smeared = edge_pixels(&["--no-direct-rays"]);
    let worst = smeared
        .iter()
        .map(|&(_, l, exact)| (l - exact).abs() / lit)
        .fold(0.0, f32::max);
    assert!(
        worst > 0.2,
        "the interpolated edge is off by {worst} at most"
    );
}

/// A scene lit by emitting faces only (the Cornell box): the per-pixel direct light changes
/// nothing, the picture is the same bit for bit with and without `--no-direct-rays`.
#[test]
fn emitting_faces_render_as_before() {
    let dir = tempfile::tempdir().unwrap();
    let render = |name: &str, extra: &[&str]| {
        let image = path(dir.path(), name);
        let mut args = vec![
            "solve",
            "scenes/cornell-box.obj",
            "-q",
            "--rays",
            "1e5",
            "--size",
            "48x48",
            "--image",
            &image,
        ];
        args.extend_from_slice(extra);
        let o = mcrad(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        read_exr(Path::new(&image)).unwrap()
    };
    let with = render("a.exr", &[]);
    let without = render("b.exr", &["--no-direct-rays"]);
    assert_eq!(with.pixels, without.pixels);
}

/// The floor and wall baked under the sun: the lightmap holds the incident irradiance `H`,
/// `E sin(45°) = 707.1 W/m²` where the sun reaches a texel's point (the black wall's front
/// too: the solution says nothing of a black surface's light, so only the direct light shows
/// there) and 0 in the shadow, nothing else since no light is reflected onto the floor. With
/// the direct light per texel (the default) every texel is one or the other within 0.1%
/// (but for the padding's averages where the edge meets a chart's border); interpolated
/// (`--no-direct-rays`) the texels along the shadow's edge take values between.
#[test]
fn a_sun_shadow_edge_is_sharp_in_bakes() {
    let texels = |extra: &[&str]| -> Vec<f32> {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("s.obj"), FLOOR_WALL_OBJ).unwrap();
        std::fs::write(dir.path().join("s.mtl"), FLOOR_WALL_MTL).unwrap();
        let out = path(dir.path(), "o.glb");
        let mut args = vec![
            "bake",
            &*path(dir.path(), "s.obj"),
            "--out",
            &out,
            "--texel",
            "0.05",
            "-q",
            "--rays",
            "2e5",
            "--mesh",
            "uniform",
            "--max-edge",
            "0.5",
            "--sun=-1,1,0,1000,0",
        ]
        .into_iter()
        .map(str::to_string)
        .collect::<Vec<_>>();
        args.extend(extra.iter().map(|s| s.to_string()));
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = mcrad(&args);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let exr = read_exr(&dir.path().join("o.lightmap.exr")).unwrap();
        exr.pixels.iter().map(|h| h.y).collect()
    };
    let lit = (1000.0 * std::f64::consts::FRAC_1_SQRT_2) as f32;
    let between = |h: &[f32]| {
        h.iter()
            .filter(|&&h| h > 1e-3 * lit && (h - lit).abs() > 1e-3 * lit)
            .count()
    };
    let sharp = texels(&[]);
    let lit_texels = sharp
        .iter()
        .filter(|&&h| (h - lit).abs() <= 1e-3 * lit)
        .count();
    // 100 m² of floor less 10 of shadow, and 10 m² of wall, at 0.05 m a texel
    assert!(lit_texels > 40_000, "{lit_texels} lit texels");
    // only padding texels where the shadow's edge meets a chart's border: the dilation
    // averages lit and dark neighbours there (28 of them)
    assert!(between(&sharp) <= 40, "{} texels between", between(&sharp));
    let smeared = texels(&["--no-direct-rays"]);
    assert!(
        between(&smeared) > 1000,
        "{} texels between",
        between(&smeared)
    );
}
