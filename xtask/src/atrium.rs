//! The generated atrium of `cargo xtask gen-scenes` (issue 35, item 7): a two-storey courtyard
//! building whose arcades (round arches on tessellated columns) run round an open court, at a
//! chosen triangle count (about 100k by default, up to 10M), for tests and benchmarks at real
//! scale. Like a real model, it mixes a few very large triangles (the floors, ceilings and outer
//! walls) with very many small ones (columns and arches).
//!
//! Layout (metres, y up): the court is 25.2 m x 15.6 m (x by z), open to the sky. Round it runs a
//! 0.6 m arcade wall and a 3.5 m deep gallery on two storeys (floor at 0 and 5.5 m, ceilings at
//! 5.1 and 9.6 m, roof at 10 m). The ground storey has 8 arches on each long side and 5 on each
//! short side; the upper storey twice as many, half as wide. Arches spring 3 cm from their
//! column's axis (a ledge on the capital), so that no wall tapers to an edge, where its
//! triangles would be slivers too thin for mcrad's `f32` geometry at 10M triangles. Red banners hang in every other
//! ground arch of the long sides, green ones on the short sides. The triangle count is reached
//! by the tessellation of the columns (a lathed profile: base moulding, taper, flared neck) and
//! of the arches; the layout never changes.
//!
//! Mcrad needs an emitter to solve, and does not yet model a sun or sky: by default an emitting
//! panel (`sky`, 37.4 m x 27.8 m) hangs 1 m above the roof, facing down over the whole
//! building, as an area-sky stand-in; light enters through the open court. It goes when
//! `--sky`/`--sun` land.
//!
//! Faces are triangles, counter-clockwise seen from the side that is seen (into the court or the
//! galleries). Faces that nothing sees (box bottoms, wall ends against another wall) are left
//! out; the floors run on under the walls and plinths, as in real models. Deterministic: no
//! randomness, fixed precision, so the same options write the same bytes.

use anyhow::{Result, bail};
use glam::{DVec3, dvec3};
use std::f64::consts::PI;
use std::io::Write;

/// Triangles asked for by default.
pub const DEFAULT_TRIANGLES: u64 = 100_000;
/// Largest triangle count asked for.
pub const MAX_TRIANGLES: u64 = 10_000_000;
/// Smallest triangle count asked for (the coarsest tessellation has about 25k).
pub const MIN_TRIANGLES: u64 = 30_000;

/// Half extent of the court, x.
const CX: f64 = 12.6;
/// Half extent of the court, z.
const CZ: f64 = 7.8;
/// Thickness of the arcade walls.
const T: f64 = 0.6;
/// Depth of the galleries (arcade wall to outer wall).
const GALLERY: f64 = 3.5;
/// Width of the solid pier at each end of an arcade (from the court's corner).
const PIER: f64 = 0.6;
/// Arches on a long (x) side and a short (z) side of the ground storey.
const BAYS: (usize, usize) = (8, 5);
/// Roof height.
const ROOF: f64 = 10.0;
/// Height of the sky panel above the roof.
const SKY_ABOVE: f64 = 1.0;
/// How far the sky panel reaches beyond the outer walls (so that the court sees no gap between
/// roof and panel).
const SKY_MARGIN: f64 = 2.0;
/// How far an arch springs from the axis of its column or the face of its pier: the ledge
/// on which it stands (no wall tapers to an edge at the springing, where its triangles would be
/// slivers).
const IMPOST: f64 = 0.03;
/// Strips across a banner.
const BANNER_STRIPS: usize = 8;

/// One storey of the arcades.
struct Storey {
    /// Floor height.
    floor: f64,
    /// Height of the springing of the arches (top of the capitals).
    spring: f64,
    /// Top of the arcade wall seen from the court (the next floor's or the roof's top).
    top_court: f64,
    /// Top of the arcade wall seen from the gallery (the gallery's ceiling).
    top_gallery: f64,
    /// Arches per side relative to the ground storey.
    bay_factor: usize,
    /// Column: shaft radius at the base (before the moulding).
    radius: f64,
    /// Plinth half width and height.
    plinth: (f64, f64),
    /// Capital height (it is square, as wide as the wall).
    capital: f64,
}

const STOREYS: [Storey; 2] = [
    Storey {
        floor: 0.0,
        spring: 3.4,
        top_court: 5.5,
        top_gallery: 5.1,
        bay_factor: 1,
        radius: 0.25,
        plinth: (0.36, 0.2),
        capital: 0.3,
    },
    Storey {
        floor: 5.5,
        spring: 8.1,
        top_court: ROOF,
        top_gallery: 9.6,
        bay_factor: 2,
        radius: 0.17,
        plinth: (0.26, 0.2),
        capital: 0.2,
    },
];

/// The tessellation: what the triangle count scales.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Tessellation {
    /// Segments round a column.
    pub segments: usize,
    /// Rings along a column's shaft.
    pub rings: usize,
    /// Segments of a semicircular arch.
    pub arch: usize,
    /// Strips across an arch's underside (the wall's thickness).
    pub depth: usize,
}

impl Tessellation {
    /// The tessellation at level `q` (> 0), every count non-decreasing in `q`.
    fn at(q: f64) -> Self {
        let n = |scale: f64, min: usize| ((scale * q).round() as usize).max(min);
        Self {
            segments: n(8.0, 12),
            rings: n(4.0, 6),
            arch: n(6.0, 8),
            depth: n(1.0, 1),
        }
    }

    /// The tessellation whose triangle count is closest to `triangles`.
    pub fn for_triangles(triangles: u64, sky_panel: bool) -> Self {
        let count = |q: f64| Self::at(q).triangles(sky_panel);
        let (mut lo, mut hi) = (0.01, 1.0);
        while count(hi) < triangles {
            hi *= 2.0;
        }
        for _ in 0..60 {
            let mid = 0.5 * (lo + hi);
            if count(mid) < triangles {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        let (a, b) = (Self::at(lo), Self::at(hi));
        if triangles.abs_diff(a.triangles(sky_panel)) < triangles.abs_diff(b.triangles(sky_panel)) {
            a
        } else {
            b
        }
    }

    /// The number of triangles [`write()`] writes with this tessellation.
    pub fn triangles(&self, sky_panel: bool) -> u64 {
        let (columns, bays, piers) = counts();
        let (s, r, a, d) = (
            self.segments as u64,
            self.rings as u64,
            self.arch as u64,
            self.depth as u64,
        );
        // plinth: 4 sides and a ring round the shaft; shaft; capital: a ring, 4 sides, 2 tops
        let column = 2 * 4 + 2 * s + 2 * s * r + 2 * s + 2 * 6;
        // court and gallery faces, underside
        let bay = 2 * (2 * a) + 2 * a * d;
        // court, gallery and inner faces, the ledge under the arch; the x sides' piers also
        // their corner's end
        let pier = 4 * 2;
        let corner_ends = 2 * 2 * 2 * 2;
        let big = 2 // court floor
            + 4 * 2 * 2 // gallery floors and ceilings (rings of 4 quads), ground storey
            + 4 * 2 * 2 // upper floor (slab top) and its ceiling
            + 4 * 2 // roof
            + 4 * 2 * 2; // outer walls, two storeys
        let banner = 4 * 2 * BANNER_STRIPS as u64 + 2 * 2;
        let banners = 2 * (BAYS.0 / 2 + BAYS.1 / 2) as u64;
        columns * column
            + bays * bay
            + piers * pier
            + corner_ends
            + big
            + banners * banner
            + if sky_panel { 2 } else { 0 }
    }
}

/// Columns, arches and piers of the whole building.
fn counts() -> (u64, u64, u64) {
    let (mut columns, mut bays) = (0, 0);
    for storey in &STOREYS {
        for n in [BAYS.0, BAYS.1] {
            let n = n * storey.bay_factor;
            columns += 2 * (n - 1);
            bays += 2 * n;
        }
    }
    (columns as u64, bays as u64, 2 * 4 * STOREYS.len() as u64)
}

/// OBJ output: vertices written once, triangles oriented to face a given way.
struct Obj<'w, W: Write> {
    out: &'w mut W,
    vertices: u64,
    triangles: u64,
}

impl<W: Write> Obj<'_, W> {
    /// Writes `p` as a vertex, returning its OBJ number.
    fn vertex(&mut self, p: DVec3) -> Result<u64> {
        writeln!(self.out, "v {:.4} {:.4} {:.4}", p.x, p.y, p.z)?;
        self.vertices += 1;
        Ok(self.vertices)
    }

    /// The triangle of vertices `i` (at `p`), counter-clockwise seen from the side `facing`.
    fn triangle(&mut self, i: [u64; 3], p: [DVec3; 3], facing: DVec3) -> Result<()> {
        let n = (p[1] - p[0]).cross(p[2] - p[0]);
        if n.dot(facing) < 0.0 {
            writeln!(self.out, "f {} {} {}", i[0], i[2], i[1])?;
        } else {
            writeln!(self.out, "f {} {} {}", i[0], i[1], i[2])?;
        }
        self.triangles += 1;
        Ok(())
    }

    /// A grid of points (`rows`, each of the same length) as triangles facing `facing` (a
    /// direction at a point).
    fn grid(&mut self, rows: &[Vec<DVec3>], facing: impl Fn(DVec3) -> DVec3) -> Result<()> {
        let mut ids = Vec::with_capacity(rows.len());
        for row in rows {
            let first = self.vertices + 1;
            for &p in row {
                self.vertex(p)?;
            }
            ids.push(first);
        }
        for j in 0..rows.len() - 1 {
            let (a, b) = (&rows[j], &rows[j + 1]);
            for i in 0..a.len() - 1 {
                let (ia, ib) = (ids[j] + i as u64, ids[j + 1] + i as u64);
                let c = 0.25 * (a[i] + a[i + 1] + b[i] + b[i + 1]);
                let f = facing(c);
                self.triangle([ia, ia + 1, ib + 1], [a[i], a[i + 1], b[i + 1]], f)?;
                self.triangle([ia, ib + 1, ib], [a[i], b[i + 1], b[i]], f)?;
            }
        }
        Ok(())
    }

    /// A planar quad `p` (in order round it) facing `facing`, as two triangles.
    fn quad(&mut self, p: [DVec3; 4], facing: DVec3) -> Result<()> {
        self.grid(&[vec![p[0], p[1]], vec![p[3], p[2]]], |_| facing)
    }

    /// Starts an object of material `material`.
    fn object(&mut self, name: &str, material: &str) -> Result<()> {
        writeln!(self.out, "o {name}\nusemtl {material}")?;
        Ok(())
    }
}

/// The local frame of one arcade side: `u` along it, `y` up, `w` across it away from the court
/// (`w = 0` is the court face, `w = T` the gallery face).
#[derive(Clone, Copy)]
struct Side {
    origin: DVec3,
    u: DVec3,
    w: DVec3,
    /// Length along `u`.
    length: f64,
    /// Whether this side's ends include the corner squares (the long sides do).
    corners: bool,
    /// Ground-storey arches.
    bays: usize,
    /// Banner material.
    banner: &'static str,
}

impl Side {
    fn at(&self, u: f64, y: f64, w: f64) -> DVec3 {
        self.origin + u * self.u + y * DVec3::Y + w * self.w
    }

    /// The four sides: the long ones along x at `z = -CZ, CZ`, the short ones along z.
    fn all() -> [Side; 4] {
        let long = |z: f64| Side {
            origin: dvec3(-CX - T, 0.0, z),
            u: DVec3::X,
            w: dvec3(0.0, 0.0, z.signum()),
            length: 2.0 * (CX + T),
            corners: true,
            bays: BAYS.0,
            banner: "red",
        };
        let short = |x: f64| Side {
            origin: dvec3(x, 0.0, -CZ),
            u: DVec3::Z,
            w: dvec3(x.signum(), 0.0, 0.0),
            length: 2.0 * CZ,
            corners: false,
            bays: BAYS.1,
            banner: "green",
        };
        [long(-CZ), long(CZ), short(-CX), short(CX)]
    }

    /// Where the end piers stop: the springing of the first arch, and the arches' pitch.
    fn piers(&self, bays: usize) -> (f64, f64) {
        let e = if self.corners { T + PIER } else { PIER };
        (e, (self.length - 2.0 * e) / bays as f64)
    }
}

/// The four sides of a box of half widths `(hu, hw)` centred at `(u, w)` from `y0` to `y1` on
/// `side`.
fn cuboid<W: Write>(
    obj: &mut Obj<W>,
    side: &Side,
    (u, w): (f64, f64),
    (hu, hw): (f64, f64),
    (y0, y1): (f64, f64),
) -> Result<()> {
    let p = |su: f64, sw: f64, y: f64| side.at(u + su * hu, y, w + sw * hw);
    let ring = [(1.0, 1.0), (-1.0, 1.0), (-1.0, -1.0), (1.0, -1.0)];
    for k in 0..4 {
        let (a, b) = (ring[k], ring[(k + 1) % 4]);
        let out = p(0.5 * (a.0 + b.0), 0.5 * (a.1 + b.1), y0) - p(0.0, 0.0, y0);
        obj.quad(
            [
                p(a.0, a.1, y0),
                p(b.0, b.1, y0),
                p(b.0, b.1, y1),
                p(a.0, a.1, y1),
            ],
            out,
        )?;
    }
    Ok(())
}

/// Radius of a column's shaft at `s` in `[0, 1]` (base to neck), relative to its base radius:
/// a torus-like base moulding, a 10% taper, a flared neck under the capital.
fn profile(s: f64) -> f64 {
    let bump = |x: f64| {
        if x.abs() < 1.0 {
            0.5 + 0.5 * (PI * x).cos()
        } else {
            0.0
        }
    };
    1.0 - 0.1 * s + 0.2 * bump((s - 0.03) / 0.04) + 0.15 * bump((s - 1.0) / 0.08)
}

/// A column of `storey` at `u` on `side`: square plinth, lathed shaft, square capital (as wide
/// as the wall). The plinth's top and the capital's bottom are rings round the shaft, so that no
/// face is partly hidden inside it.
fn column<W: Write>(
    obj: &mut Obj<W>,
    side: &Side,
    storey: &Storey,
    u: f64,
    tess: &Tessellation,
) -> Result<()> {
    let w = 0.5 * T;
    let (plinth, cap_h) = (storey.plinth, storey.capital);
    let (y0, y1) = (storey.floor + plinth.1, storey.spring - cap_h);
    let axis = side.at(u, 0.0, w);
    let n = tess.segments;
    // the shaft's points start at the squares' corners (45 degrees)
    let circle = |y: f64, r: f64| -> Vec<DVec3> {
        (0..=n)
            .map(|i| {
                let a = 0.25 * PI + 2.0 * PI * (i % n) as f64 / n as f64;
                dvec3(axis.x + r * a.cos(), y, axis.z + r * a.sin())
            })
            .collect()
    };
    // a square of half width `h` round the axis, its corners at the circle's points 0, n/4, ...
    let square = |y: f64, h: f64| -> Vec<DVec3> {
        let k = |j: usize| (j * n + 2) / 4;
        let corner = |j: usize| {
            let a = 0.25 * PI + 0.5 * PI * j as f64;
            dvec3(
                axis.x + h * 2f64.sqrt() * a.cos(),
                y,
                axis.z + h * 2f64.sqrt() * a.sin(),
            )
        };
        (0..=n)
            .map(|i| {
                let j = (0..4).find(|&j| i <= k(j + 1)).unwrap_or(3);
                let t = (i - k(j)) as f64 / (k(j + 1) - k(j)) as f64;
                corner(j).lerp(corner(j + 1), t)
            })
            .collect()
    };
    let radial = |c: DVec3| dvec3(c.x - axis.x, 0.0, c.z - axis.z);
    cuboid(obj, side, (u, w), (plinth.0, plinth.0), (storey.floor, y0))?;
    let base = storey.radius * profile(0.0);
    obj.grid(&[circle(y0, base), square(y0, plinth.0)], |_| DVec3::Y)?;
    let rows: Vec<Vec<DVec3>> = (0..=tess.rings)
        .map(|j| {
            let s = j as f64 / tess.rings as f64;
            circle(y0 + s * (y1 - y0), storey.radius * profile(s))
        })
        .collect();
    obj.grid(&rows, radial)?;
    let neck = storey.radius * profile(1.0);
    obj.grid(&[circle(y1, neck), square(y1, 0.5 * T)], |_| -DVec3::Y)?;
    cuboid(obj, side, (u, w), (0.5 * T, 0.5 * T), (y1, storey.spring))?;
    // the capital's top on either side of the wall that stands on it between two arches
    let y = storey.spring;
    for (a, b) in [(u - 0.5 * T, u - IMPOST), (u + IMPOST, u + 0.5 * T)] {
        panel_flat(obj, side, (a, b), y, DVec3::Y)?;
    }
    Ok(())
}

/// A horizontal rectangle across the wall (`w` from 0 to `T`) from `u0` to `u1` at height `y`.
fn panel_flat<W: Write>(
    obj: &mut Obj<W>,
    side: &Side,
    (u0, u1): (f64, f64),
    y: f64,
    facing: DVec3,
) -> Result<()> {
    obj.quad(
        [
            side.at(u0, y, 0.0),
            side.at(u1, y, 0.0),
            side.at(u1, y, T),
            side.at(u0, y, T),
        ],
        facing,
    )
}

/// The wall above one arch of `storey`, from `c0` to `c1` along `side`: both faces (court and
/// gallery) of the spandrels round the semicircle, and the arch's underside.
fn arch<W: Write>(
    obj: &mut Obj<W>,
    side: &Side,
    storey: &Storey,
    (c0, c1): (f64, f64),
    tess: &Tessellation,
) -> Result<()> {
    let (mid, r, y0) = (0.5 * (c0 + c1), 0.5 * (c1 - c0) - IMPOST, storey.spring);
    let n = tess.arch;
    // the arch's points, left to right (u, y)
    let arc: Vec<(f64, f64)> = (0..=n)
        .map(|k| {
            let a = PI * (1.0 - k as f64 / n as f64);
            (mid + r * a.cos(), y0 + r * a.sin())
        })
        .collect();
    for (w, top, facing) in [
        (0.0, storey.top_court, -side.w),
        (T, storey.top_gallery, side.w),
    ] {
        // the outer boundary (left edge up, top, right edge down), its corners on arch points
        // near the rays from the centre through them
        let h = top - y0;
        let corner = ((n as f64 * h.atan2(r) / PI).round() as usize).clamp(1, n / 2 - 1);
        let outer = |k: usize| -> (f64, f64) {
            if k <= corner {
                (c0, y0 + h * k as f64 / corner as f64)
            } else if k >= n - corner {
                (c1, y0 + h * (n - k) as f64 / corner as f64)
            } else {
                let t = (k - corner) as f64 / (n - 2 * corner) as f64;
                (c0 + t * (c1 - c0), top)
            }
        };
        let first = obj.vertices + 1;
        for (k, &(u, y)) in arc.iter().enumerate() {
            obj.vertex(side.at(u, y, w))?;
            let (u, y) = outer(k);
            obj.vertex(side.at(u, y, w))?;
        }
        let id = |k: usize, outer: bool| first + 2 * k as u64 + u64::from(outer);
        let at = |k: usize, o: bool| {
            let (u, y) = if o { outer(k) } else { arc[k] };
            side.at(u, y, w)
        };
        for k in 0..n {
            // (arc k, arc k+1, outer k+1) and (arc k, outer k+1, outer k)
            obj.triangle(
                [id(k, false), id(k + 1, false), id(k + 1, true)],
                [at(k, false), at(k + 1, false), at(k + 1, true)],
                facing,
            )?;
            obj.triangle(
                [id(k, false), id(k + 1, true), id(k, true)],
                [at(k, false), at(k + 1, true), at(k, true)],
                facing,
            )?;
        }
    }
    let centre = |p: DVec3| {
        let q = side.at(mid, y0, 0.0);
        let along = (p - q).dot(side.w) * side.w;
        q + along - p
    };
    let rows: Vec<Vec<DVec3>> = (0..=tess.depth)
        .map(|j| {
            let w = T * j as f64 / tess.depth as f64;
            arc.iter().map(|&(u, y)| side.at(u, y, w)).collect()
        })
        .collect();
    obj.grid(&rows, centre)
}

/// A rectangle on `side` from `(u0, y0)` to `(u1, y1)` at `w`, facing `facing`.
fn panel<W: Write>(
    obj: &mut Obj<W>,
    side: &Side,
    (u0, u1): (f64, f64),
    (y0, y1): (f64, f64),
    w: f64,
    facing: DVec3,
) -> Result<()> {
    obj.quad(
        [
            side.at(u0, y0, w),
            side.at(u1, y0, w),
            side.at(u1, y1, w),
            side.at(u0, y1, w),
        ],
        facing,
    )
}

/// The end piers of `storey` on `side`.
fn piers<W: Write>(obj: &mut Obj<W>, side: &Side, storey: &Storey) -> Result<()> {
    let (e, _) = side.piers(storey.bay_factor * side.bays);
    let l = side.length;
    // the long sides' court faces start after the corner square (the short side abuts there)
    let skip = if side.corners { T } else { 0.0 };
    let y = (storey.floor, storey.top_court);
    let g = (storey.floor, storey.top_gallery);
    for (a, b, dir) in [(0.0, e, 1.0), (l - e, l, -1.0)] {
        let (ca, cb) = if dir > 0.0 {
            (a + skip, b)
        } else {
            (a, b - skip)
        };
        panel(obj, side, (ca, cb), y, 0.0, -side.w)?;
        panel(obj, side, (a, b), g, T, side.w)?;
        let inner = if dir > 0.0 { b } else { a };
        let ledge = if dir > 0.0 {
            (b, b + IMPOST)
        } else {
            (a - IMPOST, a)
        };
        panel_flat(obj, side, ledge, storey.spring, -DVec3::Y)?;
        obj.quad(
            [
                side.at(inner, storey.floor, 0.0),
                side.at(inner, storey.floor, T),
                side.at(inner, storey.spring, T),
                side.at(inner, storey.spring, 0.0),
            ],
            dir * side.u,
        )?;
        if side.corners {
            let end = if dir > 0.0 { a } else { b };
            obj.quad(
                [
                    side.at(end, storey.floor, 0.0),
                    side.at(end, storey.floor, T),
                    side.at(end, storey.top_gallery, T),
                    side.at(end, storey.top_gallery, 0.0),
                ],
                -dir * side.u,
            )?;
        }
    }
    Ok(())
}

/// A banner hanging in front of the ground arch from `c0` to `c1` on `side`: a thin closed
/// slab, rippled across.
fn banner<W: Write>(obj: &mut Obj<W>, side: &Side, (c0, c1): (f64, f64)) -> Result<()> {
    let (mid, half) = (0.5 * (c0 + c1), 0.4 * (c1 - c0));
    let (y0, y1, thick) = (2.4, 5.4, 0.02);
    let strips = BANNER_STRIPS;
    let front: Vec<(f64, f64)> = (0..=strips)
        .map(|i| {
            let t = i as f64 / strips as f64;
            (
                mid - half + 2.0 * half * t,
                -0.14 - 0.04 * (2.0 * PI * 2.0 * t).sin(),
            )
        })
        .collect();
    let row = |y: f64, dw: f64| -> Vec<DVec3> {
        front.iter().map(|&(u, w)| side.at(u, y, w + dw)).collect()
    };
    let normal = |i: usize| {
        let (a, b) = (front[i.min(strips - 1)], front[i.min(strips - 1) + 1]);
        // the court-side normal of the strip in (u, w)
        let (du, dw) = (b.0 - a.0, b.1 - a.1);
        -du * side.w + dw * side.u
    };
    let along_u = |c: DVec3| -> usize {
        let u = (c - side.origin).dot(side.u);
        (((u - (mid - half)) / (2.0 * half) * strips as f64) as usize).min(strips - 1)
    };
    obj.grid(&[row(y0, 0.0), row(y1, 0.0)], |c| normal(along_u(c)))?;
    obj.grid(&[row(y0, thick), row(y1, thick)], |c| -normal(along_u(c)))?;
    obj.grid(&[row(y0, 0.0), row(y0, thick)], |_| -DVec3::Y)?;
    obj.grid(&[row(y1, 0.0), row(y1, thick)], |_| DVec3::Y)?;
    for (i, dir) in [(0, -1.0), (strips, 1.0)] {
        let (u, w) = front[i];
        obj.quad(
            [
                side.at(u, y0, w),
                side.at(u, y0, w + thick),
                side.at(u, y1, w + thick),
                side.at(u, y1, w),
            ],
            dir * side.u,
        )?;
    }
    Ok(())
}

/// A horizontal ring at height `y` between the rectangle of half extents `inner` and that of
/// `outer`, as four quads facing `facing`.
fn ring<W: Write>(
    obj: &mut Obj<W>,
    y: f64,
    inner: (f64, f64),
    outer: (f64, f64),
    facing: DVec3,
) -> Result<()> {
    let ((ix, iz), (ox, oz)) = (inner, outer);
    for s in [-1.0, 1.0] {
        obj.quad(
            [
                dvec3(-ox, y, s * iz),
                dvec3(ox, y, s * iz),
                dvec3(ox, y, s * oz),
                dvec3(-ox, y, s * oz),
            ],
            facing,
        )?;
        obj.quad(
            [
                dvec3(s * ix, y, -iz),
                dvec3(s * ox, y, -iz),
                dvec3(s * ox, y, iz),
                dvec3(s * ix, y, iz),
            ],
            facing,
        )?;
    }
    Ok(())
}

/// Writes the atrium's OBJ to `out` (naming `mtllib` as `mtl_name`) with `tess`; returns the
/// number of triangles written.
pub fn write(
    out: &mut impl Write,
    mtl_name: &str,
    tess: &Tessellation,
    sky_panel: bool,
) -> Result<u64> {
    let mut obj = Obj {
        out,
        vertices: 0,
        triangles: 0,
    };
    writeln!(
        obj.out,
        "# atrium: a two-storey courtyard building (metres, y up): arcades of round arches on\n\
         # columns round an open {:.1} m x {:.1} m court, galleries {GALLERY} m deep, roof at {ROOF} m.\n\
         # Tessellation: {} segments x {} rings per column, {} segments x {} strips per arch;\n\
         # {} triangles{}. Faces are counter-clockwise seen from their visible side.\n\
         # Generated by `cargo xtask gen-scenes` (xtask/src/atrium.rs); deterministic.\n\
         mtllib {mtl_name}",
        2.0 * CX,
        2.0 * CZ,
        tess.segments,
        tess.rings,
        tess.arch,
        tess.depth,
        tess.triangles(sky_panel),
        if sky_panel {
            ", with an emitting sky panel 1 m above the roof (a stand-in for a sky)"
        } else {
            ", no emitter"
        }
    )?;
    let band = (CX + T, CZ + T);
    let outer = (band.0 + GALLERY, band.1 + GALLERY);
    obj.object("court_floor", "floor")?;
    obj.quad(
        [
            dvec3(-CX, 0.0, -CZ),
            dvec3(CX, 0.0, -CZ),
            dvec3(CX, 0.0, CZ),
            dvec3(-CX, 0.0, CZ),
        ],
        DVec3::Y,
    )?;
    obj.object("gallery_floor", "floor")?;
    ring(&mut obj, 0.0, (CX, CZ), outer, DVec3::Y)?;
    ring(&mut obj, STOREYS[1].floor, (CX, CZ), outer, DVec3::Y)?;
    obj.object("ceilings", "wall")?;
    for storey in &STOREYS {
        ring(&mut obj, storey.top_gallery, band, outer, -DVec3::Y)?;
    }
    obj.object("roof", "wall")?;
    ring(&mut obj, ROOF, (CX, CZ), outer, DVec3::Y)?;
    obj.object("outer_walls", "wall")?;
    let (ox, oz) = outer;
    for storey in &STOREYS {
        let (y0, y1) = (storey.floor, storey.top_gallery);
        for s in [-1.0, 1.0] {
            obj.quad(
                [
                    dvec3(-ox, y0, s * oz),
                    dvec3(ox, y0, s * oz),
                    dvec3(ox, y1, s * oz),
                    dvec3(-ox, y1, s * oz),
                ],
                dvec3(0.0, 0.0, -s),
            )?;
            obj.quad(
                [
                    dvec3(s * ox, y0, -oz),
                    dvec3(s * ox, y0, oz),
                    dvec3(s * ox, y1, oz),
                    dvec3(s * ox, y1, -oz),
                ],
                dvec3(-s, 0.0, 0.0),
            )?;
        }
    }
    for (k, side) in Side::all().iter().enumerate() {
        for (level, storey) in STOREYS.iter().enumerate() {
            let bays = storey.bay_factor * side.bays;
            let (e, pitch) = side.piers(bays);
            obj.object(&format!("arcade_{k}_{level}"), "wall")?;
            piers(&mut obj, side, storey)?;
            for b in 0..bays {
                let c0 = e + b as f64 * pitch;
                arch(&mut obj, side, storey, (c0, c0 + pitch), tess)?;
            }
            obj.object(&format!("columns_{k}_{level}"), "column")?;
            for b in 1..bays {
                column(&mut obj, side, storey, e + b as f64 * pitch, tess)?;
            }
            if level == 0 {
                obj.object(&format!("banners_{k}"), side.banner)?;
                for b in (1..bays).step_by(2) {
                    let c0 = e + b as f64 * pitch;
                    banner(&mut obj, side, (c0, c0 + pitch))?;
                }
            }
        }
    }
    if sky_panel {
        obj.object("sky_panel", "sky")?;
        let (x, z, y) = (outer.0 + SKY_MARGIN, outer.1 + SKY_MARGIN, ROOF + SKY_ABOVE);
        obj.quad(
            [
                dvec3(-x, y, -z),
                dvec3(x, y, -z),
                dvec3(x, y, z),
                dvec3(-x, y, z),
            ],
            -DVec3::Y,
        )?;
    }
    obj.out.flush()?;
    Ok(obj.triangles)
}

/// The atrium's MTL.
pub const MTL: &str = "\
# Materials of atrium.obj. Kd is the diffuse reflectance rho (RGB), Ke the emitted radiosity
# E in W/m^2 (exitance). Generated by `cargo xtask gen-scenes`.

newmtl floor
Kd 0.5 0.45 0.38

newmtl wall
Kd 0.72 0.67 0.58

newmtl column
Kd 0.62 0.6 0.56

newmtl red
Kd 0.7 0.1 0.08

newmtl green
Kd 0.12 0.5 0.16

newmtl sky
Kd 0 0 0
Ke 10 11 12.5
";

/// Checks a triangle count asked for.
pub fn check_triangles(triangles: u64) -> Result<()> {
    if !(MIN_TRIANGLES..=MAX_TRIANGLES).contains(&triangles) {
        bail!("--triangles must be from {MIN_TRIANGLES} to {MAX_TRIANGLES}, got {triangles}");
    }
    Ok(())
}

/// The view of the pictures: from a corner of the court, 1.6 m up, across to the far arcades.
pub const CAMERA: &str = "eye=-11,1.6,-6.5,look=4,4.5,5,fov=70";

/// [`CAMERA`] as the scene file's camera (the GLB's).
pub fn camera() -> mcrad_scene_io::Camera {
    let c = mcrad_render::parse_camera(CAMERA).expect("CAMERA parses");
    mcrad_scene_io::Camera {
        eye: c.eye(),
        forward: c.forward(),
        up: c.up(),
        fov_y_degrees: c.fov_y_degrees(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mcrad_raycast::{Bvh, Ray, RayCaster};

    /// The OBJ of about `asked` triangles, and its triangle count.
    fn generate(asked: u64, sky_panel: bool) -> (Vec<u8>, u64) {
        let tess = Tessellation::for_triangles(asked, sky_panel);
        let mut obj = Vec::new();
        let written = write(&mut obj, "atrium.mtl", &tess, sky_panel).unwrap();
        assert_eq!(written, tess.triangles(sky_panel), "{tess:?}");
        (obj, written)
    }

    /// At two sizes: about the triangles asked for, the same bytes twice, loaded by mcrad
    /// without a repair (no degenerate, duplicate or split face) and one face per triangle; and
    /// every face faces the way it is seen: rays leaving the front of any face (along its
    /// normal and three tilted directions) hit only fronts, or escape through the open court.
    #[test]
    fn the_atrium_has_the_triangles_asked_for_loads_cleanly_and_faces_the_way_it_is_seen() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("atrium.mtl"), MTL).unwrap();
        for asked in [MIN_TRIANGLES, 120_000] {
            let (obj, written) = generate(asked, true);
            assert!(
                written.abs_diff(asked) * 10 <= asked,
                "{written} triangles for {asked}"
            );
            assert!(obj == generate(asked, true).0, "not deterministic");
            let path = dir.path().join("atrium.obj");
            std::fs::write(&path, &obj).unwrap();
            let loaded = mcrad_scene_io::load(&path).unwrap();
            assert!(loaded.warnings.is_empty(), "{:?}", loaded.warnings);
            assert_eq!(loaded.scene.faces().len() as u64, written);
            let mesh = mcrad_meshing::Mesh::build(&loaded.scene, mcrad_meshing::Subdivision::None)
                .unwrap();
            let triangles = mesh.triangle_positions();
            let ids: Vec<u32> = (0..triangles.len() as u32).collect();
            let bvh = Bvh::build(&triangles, &ids).unwrap();
            // a back hit on the edge of a face is a ray slipping between two faces that meet
            // there (where arches meet on a capital), not a face turned the wrong way
            let on_edge = |t: &[glam::Vec3; 3], p: glam::Vec3| {
                (0..3).any(|k| {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    let s = ((p - a).dot(b - a) / (b - a).length_squared()).clamp(0.0, 1.0);
                    p.distance(a + s * (b - a)) < 1e-3
                })
            };
            let (mut back, mut edges, mut escaped, mut rays) = (Vec::new(), 0, 0, 0);
            for (id, t) in triangles.iter().enumerate() {
                let n = (t[1] - t[0]).cross(t[2] - t[0]).normalize();
                let c = (t[0] + t[1] + t[2]) / 3.0;
                let u = (t[1] - t[0]).normalize();
                let v = n.cross(u);
                for d in [n, n + 1.5 * u, n - u + 1.2 * v, n - 0.7 * u - 1.4 * v] {
                    let ray = Ray::from_surface(c, n, d.normalize(), id as u32);
                    rays += 1;
                    match bvh.closest_hit(&ray) {
                        Some(hit) if !hit.front => {
                            if on_edge(&triangles[hit.id as usize], hit.point) {
                                edges += 1;
                            } else {
                                back.push((id, hit.id));
                            }
                        }
                        Some(_) => {}
                        None => escaped += 1,
                    }
                }
            }
            assert!(
                back.is_empty(),
                "{} back hits (from, to): {:?}",
                back.len(),
                &back[..10.min(back.len())]
            );
            assert!(
                edges * 10_000 < rays,
                "{edges} of {rays} rays slipped between faces"
            );
            // the galleries are closed: what escapes leaves through the court's opening
            assert!(escaped * 4 < rays, "{escaped} of {rays} rays escaped");
        }
    }

    /// Without the panel the atrium has two triangles fewer (and mcrad would find no emitter);
    /// the largest sizes are reached within 10% too (by count, not written); the limits hold.
    #[test]
    fn sizes_and_limits() {
        let tess = Tessellation::for_triangles(DEFAULT_TRIANGLES, true);
        assert_eq!(tess.triangles(false) + 2, tess.triangles(true));
        for asked in [1_000_000, 3_000_000, MAX_TRIANGLES] {
            let count = Tessellation::for_triangles(asked, true).triangles(true);
            assert!(count.abs_diff(asked) * 10 <= asked, "{count} for {asked}");
        }
        assert!(check_triangles(DEFAULT_TRIANGLES).is_ok());
        assert!(check_triangles(MIN_TRIANGLES - 1).is_err());
        assert!(check_triangles(MAX_TRIANGLES + 1).is_err());
    }
}
