//! `cargo xtask gen-scenes`: writes the generated experiment scenes `scenes/boxes-room.obj`
//! (+ `.mtl`), a room full of small boxes: many small patches, lit by two ceiling panels; and
//! `scenes/table-room.obj` (+ `.mtl`), the same room as one quad per wall with a table, a cabinet
//! and one small ceiling light (the adaptive-meshing experiment's scene).
//!
//! Deterministic: the layout comes from a fixed-seed SplitMix64 stream, and the numbers are
//! written with fixed precision, so rerunning rewrites the same bytes.
//!
//! Also the atrium ([`crate::atrium`]), generated on demand into `target/scenes/` (never
//! committed): `atrium.obj` (+ `atrium.mtl`, and `atrium.glb` with `--glb`) at the default
//! size, `atrium-N.obj` at `--triangles N`.

use anyhow::{Context, Result};
use glam::{DVec3, dvec3};
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// The options of `cargo xtask gen-scenes`.
#[derive(Debug, clap::Args)]
pub struct GenScenesArgs {
    /// Triangles of the atrium (about; from 30000 to 1e7), reached by tessellating its columns
    /// and arches more finely
    #[arg(long, value_name = "N", default_value_t = crate::atrium::DEFAULT_TRIANGLES,
          value_parser = crate::parse_count)]
    pub triangles: u64,
    /// No emitting sky panel above the atrium's roof (then mcrad finds no emitter until it
    /// models a sky or sun)
    #[arg(long)]
    pub no_sky_panel: bool,
    /// Also writes the atrium as GLB (atrium.glb, or atrium-N.glb), with a camera in its court
    #[arg(long)]
    pub glb: bool,
    /// Writes only the atrium, not the committed scenes of scenes/
    #[arg(long)]
    pub atrium_only: bool,
    /// Folder of the atrium [default: target/scenes in the workspace]
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

/// Writes the atrium of `args` (OBJ, MTL, and GLB if asked) into `args.out` (default
/// `target/scenes` under `root`); returns the OBJ's path.
pub fn write_atrium(root: &Path, args: &GenScenesArgs) -> Result<PathBuf> {
    use crate::atrium;
    atrium::check_triangles(args.triangles)?;
    let dir = args
        .out
        .clone()
        .unwrap_or_else(|| root.join("target/scenes"));
    std::fs::create_dir_all(&dir).with_context(|| format!("could not create {}", dir.display()))?;
    let stem = if args.triangles == atrium::DEFAULT_TRIANGLES {
        "atrium".to_string()
    } else {
        format!("atrium-{}", args.triangles)
    };
    let sky = !args.no_sky_panel;
    let tess = atrium::Tessellation::for_triangles(args.triangles, sky);
    let mtl = dir.join("atrium.mtl");
    std::fs::write(&mtl, atrium::MTL)
        .with_context(|| format!("could not write {}", mtl.display()))?;
    let path = dir.join(format!("{stem}.obj"));
    let start = std::time::Instant::now();
    let file = std::fs::File::create(&path)
        .with_context(|| format!("could not write {}", path.display()))?;
    let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
    let triangles = atrium::write(&mut out, "atrium.mtl", &tess, sky)
        .with_context(|| format!("could not write {}", path.display()))?;
    eprintln!(
        "wrote {} ({triangles} triangles, {tess:?}) in {:.1} s",
        path.display(),
        start.elapsed().as_secs_f64()
    );
    if args.glb {
        let loaded = mcrad_scene_io::load(&path)?;
        for warning in &loaded.warnings {
            eprintln!("warning: {warning}");
        }
        let glb = mcrad_bake::glb_from_scene(&loaded.scene, Some(&atrium::camera()))?;
        let glb_path = dir.join(format!("{stem}.glb"));
        std::fs::write(&glb_path, glb)
            .with_context(|| format!("could not write {}", glb_path.display()))?;
        eprintln!("wrote {}", glb_path.display());
    }
    Ok(path)
}

/// Room extent (m): x width, y height, z depth.
const ROOM: DVec3 = DVec3::new(5.0, 2.6, 4.0);
/// Floor grid of box sites (x by z); a site holds a box with probability [`FILL`].
const GRID: (usize, usize) = (20, 15);
const FILL: f64 = 0.85;
/// A box carries a smaller box on its top with this probability.
const STACK: f64 = 0.5;
/// Seed of the layout.
const SEED: u64 = 5;

/// SplitMix64: a tiny deterministic generator (enough for a layout).
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }

    fn range(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.next()
    }
}

/// OBJ text under construction.
struct Obj {
    text: String,
    vertices: usize,
}

impl Obj {
    /// A quad `p` (in order around it) facing `normal`: written counter-clockwise seen from
    /// that side.
    fn quad(&mut self, material: &str, mut p: [DVec3; 4], normal: DVec3) {
        if (p[1] - p[0]).cross(p[2] - p[0]).dot(normal) < 0.0 {
            p.reverse();
        }
        for v in p {
            let _ = writeln!(self.text, "v {:.4} {:.4} {:.4}", v.x, v.y, v.z);
        }
        let n = self.vertices;
        let _ = writeln!(
            self.text,
            "usemtl {material}\nf {} {} {} {}",
            n + 1,
            n + 2,
            n + 3,
            n + 4
        );
        self.vertices += 4;
    }

    /// A box without a bottom: footprint centred at `(cx, cz)`, half sizes `(hx, hz)`, turned by
    /// `angle` about +y, from height `y0` up `h`. Returns its top height.
    fn block(
        &mut self,
        material: &str,
        (cx, cz): (f64, f64),
        (hx, hz): (f64, f64),
        angle: f64,
        y0: f64,
        h: f64,
    ) -> f64 {
        let (s, c) = angle.sin_cos();
        let at = |u: f64, w: f64, y: f64| dvec3(cx + c * u - s * w, y, cz + s * u + c * w);
        let ring = [(hx, hz), (-hx, hz), (-hx, -hz), (hx, -hz)];
        let y1 = y0 + h;
        let _ = writeln!(self.text, "o box_{}", self.vertices / 4);
        self.quad(material, ring.map(|(u, w)| at(u, w, y1)), DVec3::Y);
        for k in 0..4 {
            let (a, b) = (ring[k], ring[(k + 1) % 4]);
            let mid = at(0.5 * (a.0 + b.0), 0.5 * (a.1 + b.1), y0);
            let outward = mid - dvec3(cx, y0, cz);
            self.quad(
                material,
                [
                    at(a.0, a.1, y0),
                    at(b.0, b.1, y0),
                    at(b.0, b.1, y1),
                    at(a.0, a.1, y1),
                ],
                outward,
            );
        }
        y1
    }
}

/// The floor, ceiling and walls of the room as one quad each, facing in; the wall at `x = w`
/// of material `accent`.
fn walls(obj: &mut Obj, accent: &str) {
    let (w, h, d) = (ROOM.x, ROOM.y, ROOM.z);
    let room = [
        (
            "floor",
            "floor",
            [
                dvec3(0., 0., 0.),
                dvec3(w, 0., 0.),
                dvec3(w, 0., d),
                dvec3(0., 0., d),
            ],
            DVec3::Y,
        ),
        (
            "ceiling",
            "wall",
            [
                dvec3(0., h, 0.),
                dvec3(w, h, 0.),
                dvec3(w, h, d),
                dvec3(0., h, d),
            ],
            -DVec3::Y,
        ),
        (
            "wall_x0",
            "wall",
            [
                dvec3(0., 0., 0.),
                dvec3(0., 0., d),
                dvec3(0., h, d),
                dvec3(0., h, 0.),
            ],
            DVec3::X,
        ),
        (
            "wall_x1",
            accent,
            [
                dvec3(w, 0., 0.),
                dvec3(w, 0., d),
                dvec3(w, h, d),
                dvec3(w, h, 0.),
            ],
            -DVec3::X,
        ),
        (
            "wall_z0",
            "wall",
            [
                dvec3(0., 0., 0.),
                dvec3(w, 0., 0.),
                dvec3(w, h, 0.),
                dvec3(0., h, 0.),
            ],
            DVec3::Z,
        ),
        (
            "wall_z1",
            "wall",
            [
                dvec3(0., 0., d),
                dvec3(w, 0., d),
                dvec3(w, h, d),
                dvec3(0., h, d),
            ],
            -DVec3::Z,
        ),
    ];
    for (name, material, p, n) in room {
        let _ = writeln!(obj.text, "o {name}");
        obj.quad(material, p, n);
    }
}

/// The OBJ and MTL text of the room.
pub fn boxes_room() -> (String, String) {
    let mut obj = Obj {
        text: String::from(
            "# boxes-room: a 5 m x 2.6 m x 4 m room (metres) whose floor holds a few hundred small\n\
             # boxes, some stacked (five faces each, no bottoms), lit by two 0.6 m x 0.6 m ceiling\n\
             # panels hanging 1 cm below the ceiling. Faces are counter-clockwise seen from their\n\
             # lit side. Generated by `cargo xtask gen-scenes` (xtask/src/gen_scenes.rs, fixed seed)\n\
             # for the speed-vs-error experiment: a scene with many small patches.\n\
             mtllib boxes-room.mtl\n",
        ),
        vertices: 0,
    };
    walls(&mut obj, "accent");
    let (w, h, d) = (ROOM.x, ROOM.y, ROOM.z);
    for (k, cx) in [1.5, 3.5].into_iter().enumerate() {
        let _ = writeln!(obj.text, "o light_{k}");
        let (y, cz, r) = (h - 0.01, 2.0, 0.3);
        obj.quad(
            "light",
            [
                dvec3(cx - r, y, cz - r),
                dvec3(cx + r, y, cz - r),
                dvec3(cx + r, y, cz + r),
                dvec3(cx - r, y, cz + r),
            ],
            -DVec3::Y,
        );
    }
    let mut rng = Rng(SEED);
    let colours = ["red", "blue", "yellow", "grey"];
    let (cell_x, cell_z) = ((w - 0.4) / GRID.0 as f64, (d - 0.4) / GRID.1 as f64);
    for i in 0..GRID.0 {
        for j in 0..GRID.1 {
            if rng.next() >= FILL {
                continue;
            }
            let cx = 0.2 + (i as f64 + 0.5) * cell_x + rng.range(-0.2, 0.2) * cell_x;
            let cz = 0.2 + (j as f64 + 0.5) * cell_z + rng.range(-0.2, 0.2) * cell_z;
            let (hx, hz) = (rng.range(0.03, 0.08), rng.range(0.03, 0.08));
            let angle = rng.range(0.0, std::f64::consts::PI);
            let colour = colours[(rng.next() * 4.0) as usize % 4];
            let top = obj.block(colour, (cx, cz), (hx, hz), angle, 0.0, rng.range(0.04, 0.5));
            if rng.next() < STACK {
                let s = rng.range(0.4, 0.8);
                let colour = colours[(rng.next() * 4.0) as usize % 4];
                let turn = angle + rng.range(-0.5, 0.5);
                obj.block(
                    colour,
                    (cx, cz),
                    (s * hx, s * hz),
                    turn,
                    top,
                    rng.range(0.03, 0.15),
                );
            }
        }
    }
    let mtl = "\
# Materials of boxes-room.obj. Kd is the diffuse reflectance rho (RGB), Ke the emitted radiosity
# E in W/m^2 (exitance). Generated by `cargo xtask gen-scenes`.

newmtl wall
Kd 0.7 0.7 0.68

newmtl accent
Kd 0.3 0.5 0.6

newmtl floor
Kd 0.45 0.35 0.25

newmtl red
Kd 0.7 0.12 0.1

newmtl blue
Kd 0.12 0.2 0.65

newmtl yellow
Kd 0.75 0.65 0.15

newmtl grey
Kd 0.5 0.5 0.5

newmtl light
Kd 0.78 0.78 0.78
Ke 60 56 48
"
    .to_string();
    (obj.text, mtl)
}

/// The OBJ and MTL text of the table room: the same 5 m x 2.6 m x 4 m room as one quad per
/// wall, a table (a 1.4 m x 0.8 m top at 0.76 m on four legs), a cabinet standing on the floor
/// near a wall, and one 0.4 m x 0.4 m ceiling light: the scene of issue 15, whose shadows and
/// contact lines a uniform mesh washes out.
pub fn table_room() -> (String, String) {
    let mut obj = Obj {
        text: String::from(
            "# table-room: a 5 m x 2.6 m x 4 m room (metres) given as one quad per wall, with a\n\
             # table (1.4 m x 0.8 m top at 0.76 m, four 5 cm legs), a 0.9 m x 0.5 m x 1.8 m cabinet\n\
             # near a wall and one 0.4 m x 0.4 m light 1 cm below the ceiling. Faces are\n\
             # counter-clockwise seen from their lit side. Generated by `cargo xtask gen-scenes`\n\
             # (xtask/src/gen_scenes.rs) for the adaptive-meshing experiment.\n\
             mtllib table-room.mtl\n",
        ),
        vertices: 0,
    };
    walls(&mut obj, "wall");
    let (h, r) = (ROOM.y - 0.01, 0.2);
    let (lx, lz) = (2.3, 2.1);
    let _ = writeln!(obj.text, "o light");
    obj.quad(
        "light",
        [
            dvec3(lx - r, h, lz - r),
            dvec3(lx + r, h, lz - r),
            dvec3(lx + r, h, lz + r),
            dvec3(lx - r, h, lz + r),
        ],
        -DVec3::Y,
    );
    // The table: a top box with a bottom, on four legs.
    let (tx, tz, thx, thz, ty0, ty1) = (2.0, 2.3, 0.7, 0.4, 0.72, 0.76);
    obj.block("wood", (tx, tz), (thx, thz), 0.0, ty0, ty1 - ty0);
    obj.quad(
        "wood",
        [
            dvec3(tx - thx, ty0, tz - thz),
            dvec3(tx + thx, ty0, tz - thz),
            dvec3(tx + thx, ty0, tz + thz),
            dvec3(tx - thx, ty0, tz + thz),
        ],
        -DVec3::Y,
    );
    for (sx, sz) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
        let (cx, cz) = (tx + sx * (thx - 0.06), tz + sz * (thz - 0.06));
        obj.block("wood", (cx, cz), (0.025, 0.025), 0.0, 0.0, ty0);
    }
    // The cabinet, 10 cm from the wall z = 0.
    obj.block("cabinet", (4.0, 0.35), (0.45, 0.25), 0.0, 0.0, 1.8);
    let mtl = "\
# Materials of table-room.obj. Kd is the diffuse reflectance rho (RGB), Ke the emitted radiosity
# E in W/m^2 (exitance). Generated by `cargo xtask gen-scenes`.

newmtl wall
Kd 0.7 0.7 0.68

newmtl floor
Kd 0.45 0.35 0.25

newmtl wood
Kd 0.55 0.38 0.22

newmtl cabinet
Kd 0.3 0.45 0.6

newmtl light
Kd 0.78 0.78 0.78
Ke 270 252 216
"
    .to_string();
    (obj.text, mtl)
}

/// Writes `scenes/boxes-room.obj`, `scenes/table-room.obj` and their `.mtl` under `root`.
pub fn run(root: &Path) -> Result<()> {
    let (obj, mtl) = boxes_room();
    let (table, table_mtl) = table_room();
    for (name, text) in [
        ("boxes-room.obj", obj),
        ("boxes-room.mtl", mtl),
        ("table-room.obj", table),
        ("table-room.mtl", table_mtl),
    ] {
        let path = root.join("scenes").join(name);
        std::fs::write(&path, text)
            .with_context(|| format!("could not write {}", path.display()))?;
        eprintln!("wrote {}", path.display());
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    #[test]
    fn the_room_is_deterministic_and_loads() {
        let (a, m) = super::boxes_room();
        assert_eq!(a, super::boxes_room().0);
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("boxes-room.obj"), &a).unwrap();
        std::fs::write(dir.path().join("boxes-room.mtl"), m).unwrap();
        let scene = mcrad_scene_io::load(&dir.path().join("boxes-room.obj"))
            .unwrap()
            .scene;
        assert!(scene.faces().len() > 1000, "{} faces", scene.faces().len());
        let (t, m) = super::table_room();
        std::fs::write(dir.path().join("table-room.obj"), &t).unwrap();
        std::fs::write(dir.path().join("table-room.mtl"), m).unwrap();
        let scene = mcrad_scene_io::load(&dir.path().join("table-room.obj"))
            .unwrap()
            .scene;
        assert_eq!(scene.faces().len(), 6 + 1 + 6 + 4 * 5 + 5);
    }
}
