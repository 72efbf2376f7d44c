//! The lightmap atlas: charts packed into one square image, texels covered by each chart, and
//! dilation into the padding.

use glam::{DVec2, DVec3, Vec3};

use crate::BakeError;
use crate::charts::Chart;

/// Where each chart sits in a square atlas of `size × size` texels.
#[derive(Debug, Clone)]
pub(crate) struct Packing {
    /// Edge of the atlas in texels (a power of two).
    pub size: u32,
    /// Per chart, the atlas texel of its rectangle's top-left corner; the chart's coordinate
    /// `q` (texels from its bounding box's corner) is at atlas position `corner + padding + q`.
    pub corners: Vec<[u32; 2]>,
    /// Per chart, its rectangle's width and height in texels, padding included.
    pub rects: Vec<[u32; 2]>,
}

/// The rectangle a chart takes, padding included: `ceil(size) + 1 + 2 padding` per axis.
fn rect(chart: &Chart, padding: u32) -> Result<[u32; 2], BakeError> {
    let side = |s: f64| -> Option<u32> {
        let t = s.ceil() + 1.0 + 2.0 * padding as f64;
        (t.is_finite() && t <= u32::MAX as f64 / 2.0).then_some(t as u32)
    };
    match (side(chart.size.x), side(chart.size.y)) {
        (Some(w), Some(h)) => Ok([w, h]),
        _ => Err(BakeError::ChartTooLarge {
            texels: chart.size.x.max(chart.size.y),
            limit: 0,
        }),
    }
}

/// Packs the charts' rectangles into the smallest power-of-two square atlas (from 64 up to
/// `max_size`) that holds them all, tallest first (ties: wider first, then chart order), so the
/// packing is a function of the charts alone.
pub(crate) fn pack(charts: &[Chart], padding: u32, max_size: u32) -> Result<Packing, BakeError> {
    let rects = charts
        .iter()
        .map(|c| rect(c, padding))
        .collect::<Result<Vec<_>, _>>()?;
    if let Some(&[w, h]) = rects.iter().find(|r| r[0].max(r[1]) > max_size) {
        return Err(BakeError::ChartTooLarge {
            texels: f64::from(w.max(h)),
            limit: max_size,
        });
    }
    let area: f64 = rects
        .iter()
        .map(|r| f64::from(r[0]) * f64::from(r[1]))
        .sum();
    let mut order: Vec<usize> = (0..rects.len()).collect();
    order.sort_by_key(|&i| {
        (
            std::cmp::Reverse(rects[i][1]),
            std::cmp::Reverse(rects[i][0]),
            i,
        )
    });
    let mut size = 64u32;
    while f64::from(size) * f64::from(size) < area && size < max_size {
        size *= 2;
    }
    loop {
        let side = i32::try_from(size).expect("max_size fits in i32");
        let mut allocator = etagere::AtlasAllocator::new(etagere::size2(side, side));
        let mut corners = vec![[0u32; 2]; rects.len()];
        let fits = order.iter().all(|&i| {
            let [w, h] = rects[i];
            match allocator.allocate(etagere::size2(w as i32, h as i32)) {
                Some(a) => {
                    corners[i] = [a.rectangle.min.x as u32, a.rectangle.min.y as u32];
                    true
                }
                None => false,
            }
        });
        if fits {
            return Ok(Packing {
                size,
                corners,
                rects,
            });
        }
        if size >= max_size {
            return Err(BakeError::AtlasFull {
                texels: area,
                limit: max_size,
            });
        }
        size *= 2;
    }
}

/// Where a texel of a chart takes its value: the point of the chart nearest to the texel's
/// centre (inside the chart), or nothing when the chart does not reach the texel.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Sample {
    /// Index into the chart's triangle list of the triangle holding the point.
    pub triangle: u32,
    /// The point in scene units.
    pub point: DVec3,
}

/// The texels of a chart's rectangle (row-major, `rect[0] × rect[1]`) that the chart covers or
/// touches: every texel whose centre lies within `0.71` texels (half a diagonal) of one of its
/// triangles, with the chart point nearest to that centre. `corners[k]` are the world corners
/// of the chart's `k`-th triangle.
pub(crate) fn samples(
    chart: &Chart,
    corners: &[[Vec3; 3]],
    rect: [u32; 2],
    padding: u32,
    texel: f64,
) -> Vec<Option<Sample>> {
    let [w, h] = rect;
    let mut best: Vec<Option<(f64, Sample)>> = vec![None; (w * h) as usize];
    let pad = f64::from(padding);
    for (k, tri) in corners.iter().enumerate() {
        let q = tri.map(|p| chart.flatten(p.as_dvec3(), texel));
        let lo = q[0].min(q[1]).min(q[2]) + pad - 1.0;
        let hi = q[0].max(q[1]).max(q[2]) + pad + 1.0;
        let x0 = lo.x.floor().max(0.0) as u32;
        let y0 = lo.y.floor().max(0.0) as u32;
        let x1 = (hi.x.ceil() as u32).min(w);
        let y1 = (hi.y.ceil() as u32).min(h);
        let centroid = (q[0] + q[1] + q[2]) / 3.0;
        for y in y0..y1 {
            for x in x0..x1 {
                let c = DVec2::new(f64::from(x) + 0.5 - pad, f64::from(y) + 0.5 - pad);
                let near = closest_on_triangle(c, q);
                let d = (near - c).length();
                if d > 0.71 {
                    continue;
                }
                let slot = &mut best[(y * w + x) as usize];
                if slot.is_none_or(|(b, _)| d < b) {
                    // a hair inside the triangle, so the point lies on it, not on its edge;
                    // placed by its barycentric weights on the triangle's own corners (exact
                    // also for a triangle a little off the chart's plane)
                    let inside = near + (centroid - near) * 1e-4;
                    let w = barycentric(inside, q);
                    let point = tri[0].as_dvec3() * w[0]
                        + tri[1].as_dvec3() * w[1]
                        + tri[2].as_dvec3() * w[2];
                    *slot = Some((
                        d,
                        Sample {
                            triangle: k as u32,
                            point,
                        },
                    ));
                }
            }
        }
    }
    best.into_iter().map(|b| b.map(|(_, s)| s)).collect()
}

/// Barycentric weights of `p` in triangle `t` (in the plane; the triangle non-degenerate).
fn barycentric(p: DVec2, t: [DVec2; 3]) -> [f64; 3] {
    let (e1, e2, d) = (t[1] - t[0], t[2] - t[0], p - t[0]);
    let det = e1.perp_dot(e2);
    let u = d.perp_dot(e2) / det;
    let v = e1.perp_dot(d) / det;
    [1.0 - u - v, u, v]
}

/// The point of triangle `t` nearest to `p` (all in the plane).
fn closest_on_triangle(p: DVec2, t: [DVec2; 3]) -> DVec2 {
    let [a, b, c] = t;
    let (ab, ac, ap) = (b - a, c - a, p - a);
    let (d1, d2) = (ab.dot(ap), ac.dot(ap));
    if d1 <= 0.0 && d2 <= 0.0 {
        return a;
    }
    let bp = p - b;
    let (d3, d4) = (ab.dot(bp), ac.dot(bp));
    if d3 >= 0.0 && d4 <= d3 {
        return b;
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        return a + ab * (d1 / (d1 - d3));
    }
    let cp = p - c;
    let (d5, d6) = (ab.dot(cp), ac.dot(cp));
    if d6 >= 0.0 && d5 <= d6 {
        return c;
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        return a + ac * (d2 / (d2 - d6));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
    }
    let denom = 1.0 / (va + vb + vc);
    a + ab * (vb * denom) + ac * (vc * denom)
}

/// Fills empty texels (`None`) of a `size × size` image from their filled neighbours, `passes`
/// times: each pass gives every empty texel with a filled 8-neighbour the mean of those
/// neighbours. Bilinear lookups up to `passes` texels outside a chart then read the chart's own
/// values, never an empty texel. Texels still empty afterwards become zero.
pub(crate) fn dilate(image: &mut [Option<Vec3>], size: u32, passes: u32) -> Vec<Vec3> {
    let s = size as i64;
    // A pass reads the image as the previous pass left it: its fills are gathered first and
    // written after (only the texels at the front, not a copy of the whole image).
    let mut fills: Vec<(usize, Vec3)> = Vec::new();
    for _ in 0..passes {
        fills.clear();
        for y in 0..s {
            for x in 0..s {
                if image[(y * s + x) as usize].is_some() {
                    continue;
                }
                let (mut sum, mut n) = (Vec3::ZERO, 0.0f32);
                for (dx, dy) in [
                    (-1, -1),
                    (0, -1),
                    (1, -1),
                    (-1, 0),
                    (1, 0),
                    (-1, 1),
                    (0, 1),
                    (1, 1),
                ] {
                    let (nx, ny) = (x + dx, y + dy);
                    if (0..s).contains(&nx)
                        && (0..s).contains(&ny)
                        && let Some(v) = image[(ny * s + nx) as usize]
                    {
                        sum += v;
                        n += 1.0;
                    }
                }
                if n > 0.0 {
                    fills.push(((y * s + x) as usize, sum / n));
                }
            }
        }
        if fills.is_empty() {
            break;
        }
        for &(i, v) in &fills {
            image[i] = Some(v);
        }
    }
    image.iter().map(|v| v.unwrap_or(Vec3::ZERO)).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::charts::charts_of;

    fn square(side: f32) -> (Vec<[u32; 3]>, Vec<Option<[Vec3; 3]>>) {
        let p = [
            Vec3::ZERO,
            Vec3::new(side, 0.0, 0.0),
            Vec3::new(side, side, 0.0),
            Vec3::new(0.0, side, 0.0),
        ];
        let tris = vec![[0, 1, 2], [0, 2, 3]];
        let corners = tris
            .iter()
            .map(|t| Some(t.map(|i| p[i as usize])))
            .collect();
        (tris, corners)
    }

    #[test]
    fn charts_do_not_overlap_and_fit_the_atlas() {
        let mut charts = Vec::new();
        for (i, side) in [1.0, 3.0, 0.5, 2.0, 0.25, 1.5].into_iter().enumerate() {
            let (tris, corners) = square(side);
            charts.extend(charts_of(i, &tris, &corners, 0.05));
        }
        let packing = pack(&charts, 2, 4096).unwrap();
        let mut owner = vec![usize::MAX; (packing.size * packing.size) as usize];
        for (i, (c, r)) in packing.corners.iter().zip(&packing.rects).enumerate() {
            for y in c[1]..c[1] + r[1] {
                for x in c[0]..c[0] + r[0] {
                    assert!(x < packing.size && y < packing.size);
                    let o = &mut owner[(y * packing.size + x) as usize];
                    assert_eq!(*o, usize::MAX, "charts {i} and {o} overlap");
                    *o = i;
                }
            }
        }
        // a chart larger than the largest atlas is refused
        assert!(matches!(
            pack(&charts, 2, 32),
            Err(BakeError::ChartTooLarge { .. })
        ));
    }

    #[test]
    fn samples_cover_the_chart_and_stay_on_it() {
        let (tris, corners) = square(1.0);
        let chart = &charts_of(0, &tris, &corners, 0.1)[0];
        let world: Vec<[Vec3; 3]> = chart
            .triangles
            .iter()
            .map(|&k| corners[k as usize].unwrap())
            .collect();
        let r = rect(chart, 2).unwrap();
        let s = samples(chart, &world, r, 2, 0.1);
        // 10 x 10 texels inside, plus the ring of texels whose centre is within 0.71 of the
        // square (the 4 corner texels of that ring are farther: sqrt(0.5) = 0.707 < 0.71, in)
        let covered = s.iter().filter(|x| x.is_some()).count();
        assert_eq!(covered, 12 * 12, "{r:?}");
        for x in s.iter().flatten() {
            let p = x.point;
            assert!(p.z.abs() < 1e-12 && (0.0..=1.0).contains(&p.x) && (0.0..=1.0).contains(&p.y));
        }
    }

    #[test]
    fn dilation_fills_the_padding_from_the_chart() {
        let mut image = vec![None; 16];
        image[5] = Some(Vec3::ONE);
        let out = dilate(&mut image, 4, 1);
        for (i, v) in out.iter().enumerate() {
            let (x, y) = (i % 4, i / 4);
            let near = x <= 2 && y <= 2;
            assert_eq!(*v, if near { Vec3::ONE } else { Vec3::ZERO }, "{x},{y}");
        }
    }
}
