//! Log–log scatter/line plots written as PNG. Text is drawn from an embedded 8×8 bitmap font (font8x8), so
//! plots render the same on any machine, with no system fonts.

use std::path::Path;

/// One data series.
pub struct Series {
    /// Legend text.
    pub name: String,
    /// RGB colour.
    pub color: [u8; 3],
    /// Points (x, y), both positive (log axes); others are skipped.
    pub points: Vec<(f64, f64)>,
    /// Join the points (in the given order) with lines.
    pub lines: bool,
    /// A text beside each point (empty: none; else one per point).
    pub labels: Vec<String>,
    /// A power law `y = exp(ln_a) · x^k` drawn as a thin line over the series' x range: `(k, ln_a)`.
    pub fit: Option<(f64, f64)>,
}

/// A log–log plot.
pub struct Plot {
    /// Title (top).
    pub title: String,
    /// x-axis label.
    pub x_label: String,
    /// y-axis label.
    pub y_label: String,
    /// The series.
    pub series: Vec<Series>,
}

/// Colours for up to eight series.
pub const PALETTE: [[u8; 3]; 8] = [
    [31, 119, 180],
    [214, 39, 40],
    [44, 160, 44],
    [255, 127, 14],
    [148, 103, 189],
    [140, 86, 75],
    [227, 119, 194],
    [23, 190, 207],
];

const W: usize = 1070;
const H: usize = 640;
const LEFT: usize = 110;
const RIGHT: usize = 360;
const TOP: usize = 50;
const BOTTOM: usize = 80;

struct Canvas {
    px: Vec<u8>,
}

impl Canvas {
    fn new() -> Self {
        Self {
            px: vec![255; W * H * 3],
        }
    }

    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < W && (y as usize) < H {
            let o = 3 * (y as usize * W + x as usize);
            self.px[o..o + 3].copy_from_slice(&c);
        }
    }

    fn rect(&mut self, x0: i64, y0: i64, x1: i64, y1: i64, c: [u8; 3]) {
        for y in y0..=y1 {
            for x in x0..=x1 {
                self.set(x, y, c);
            }
        }
    }

    fn line(&mut self, (x0, y0): (i64, i64), (x1, y1): (i64, i64), c: [u8; 3], width: i64) {
        let (dx, dy) = ((x1 - x0).abs(), -(y1 - y0).abs());
        let (sx, sy) = (if x0 < x1 { 1 } else { -1 }, if y0 < y1 { 1 } else { -1 });
        let (mut x, mut y, mut err) = (x0, y0, dx + dy);
        loop {
            self.rect(x, y, x + width - 1, y + width - 1, c);
            if x == x1 && y == y1 {
                break;
            }
            let e2 = 2 * err;
            if e2 >= dy {
                err += dy;
                x += sx;
            }
            if e2 <= dx {
                err += dx;
                y += sy;
            }
        }
    }

    /// Text at (x, y) (top-left), scale `s`; `vertical` runs it bottom-to-top.
    fn text(&mut self, x: i64, y: i64, s: &str, scale: i64, c: [u8; 3], vertical: bool) {
        for (k, ch) in s.chars().enumerate() {
            let glyph = font8x8::legacy::BASIC_LEGACY
                .get(ch as usize)
                .copied()
                .unwrap_or([0; 8]);
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..8 {
                    if bits >> col & 1 == 1 {
                        let (gx, gy) = (8 * k as i64 + col, row as i64);
                        let (px, py) = if vertical {
                            (x + gy * scale, y - gx * scale)
                        } else {
                            (x + gx * scale, y + gy * scale)
                        };
                        self.rect(px, py, px + scale - 1, py + scale - 1, c);
                    }
                }
            }
        }
    }
}

fn text_width(s: &str, scale: i64) -> i64 {
    8 * scale * s.chars().count() as i64
}

fn decade_label(e: i32) -> String {
    match e {
        0 => "1".into(),
        1 => "10".into(),
        -1 => "0.1".into(),
        _ => format!("1e{e}"),
    }
}

/// Renders `plot` to a PNG file at `path`.
///
/// # Errors
/// A message when there is nothing to plot or the file cannot be written.
pub fn render_png(plot: &Plot, path: &Path) -> Result<(), String> {
    let px = render(plot).map_err(|e| format!("{}: {e}", path.display()))?;
    let file = std::fs::File::create(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let mut enc = png::Encoder::new(std::io::BufWriter::new(file), W as u32, H as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    let mut w = enc
        .write_header()
        .map_err(|e| format!("{}: {e}", path.display()))?;
    w.write_image_data(&px)
        .map_err(|e| format!("{}: {e}", path.display()))?;
    w.finish().map_err(|e| format!("{}: {e}", path.display()))
}

/// Renders `plot` to RGB pixels (`W` × `H`).
fn render(plot: &Plot) -> Result<Vec<u8>, String> {
    let pts: Vec<(f64, f64)> = plot
        .series
        .iter()
        .flat_map(|s| s.points.iter().copied())
        .filter(|&(x, y)| x > 0.0 && y > 0.0 && x.is_finite() && y.is_finite())
        .collect();
    if pts.is_empty() {
        return Err("no positive data to plot".into());
    }
    let range = |v: Vec<f64>| {
        let lo = v.iter().copied().fold(f64::INFINITY, f64::min).log10();
        let hi = v.iter().copied().fold(f64::NEG_INFINITY, f64::max).log10();
        let (mut a, mut b) = (lo.floor(), hi.ceil());
        if b <= a {
            b = a + 1.0;
        }
        if b - a < 1.0 {
            a -= 0.5;
        }
        (a, b)
    };
    let (xa, xb) = range(pts.iter().map(|p| p.0).collect());
    let (ya, yb) = range(pts.iter().map(|p| p.1).collect());
    let (pw, ph) = ((W - LEFT - RIGHT) as f64, (H - TOP - BOTTOM) as f64);
    let to_px = |x: f64, y: f64| {
        (
            LEFT as i64 + ((x.log10() - xa) / (xb - xa) * pw).round() as i64,
            (H - BOTTOM) as i64 - ((y.log10() - ya) / (yb - ya) * ph).round() as i64,
        )
    };
    let mut c = Canvas::new();
    let (black, grid) = ([0, 0, 0], [225, 225, 225]);
    // Decade grid and tick labels.
    for e in (xa.ceil() as i32)..=(xb.floor() as i32) {
        let (x, _) = to_px(10f64.powi(e), 10f64.powf(ya));
        c.line((x, TOP as i64), (x, (H - BOTTOM) as i64), grid, 1);
        let l = decade_label(e);
        c.text(
            x - text_width(&l, 2) / 2,
            (H - BOTTOM) as i64 + 8,
            &l,
            2,
            black,
            false,
        );
    }
    for e in (ya.ceil() as i32)..=(yb.floor() as i32) {
        let (_, y) = to_px(10f64.powf(xa), 10f64.powi(e));
        c.line((LEFT as i64, y), ((W - RIGHT) as i64, y), grid, 1);
        let l = decade_label(e);
        c.text(
            LEFT as i64 - 8 - text_width(&l, 2),
            y - 8,
            &l,
            2,
            black,
            false,
        );
    }
    // Frame.
    let (l, r, t, b) = (
        LEFT as i64,
        (W - RIGHT) as i64,
        TOP as i64,
        (H - BOTTOM) as i64,
    );
    c.line((l, t), (r, t), black, 1);
    c.line((l, b), (r, b), black, 1);
    c.line((l, t), (l, b), black, 1);
    c.line((r, t), (r, b), black, 1);
    // Series.
    for s in &plot.series {
        let p: Vec<(i64, i64)> = s
            .points
            .iter()
            .filter(|&&(x, y)| x > 0.0 && y > 0.0 && x.is_finite() && y.is_finite())
            .map(|&(x, y)| to_px(x, y))
            .collect();
        if s.lines {
            for w in p.windows(2) {
                c.line(w[0], w[1], s.color, 2);
            }
        }
        if let Some((k, ln_a)) = s.fit {
            // Over the series' own x range (so the line stays near the plot), in pieces of a few pixels,
            // each drawn only when inside the frame.
            let xs: Vec<f64> = s.points.iter().map(|p| p.0).filter(|x| *x > 0.0).collect();
            let (lo, hi) = xs
                .iter()
                .fold((f64::INFINITY, 0.0_f64), |(a, b), &x| (a.min(x), b.max(x)));
            if lo.is_finite() && hi > lo {
                let steps = 64;
                let at = |i: usize| {
                    let x = (lo.ln() + (hi.ln() - lo.ln()) * i as f64 / steps as f64).exp();
                    to_px(x, (ln_a + k * x.ln()).exp())
                };
                let inside = |(x, y): (i64, i64)| {
                    x >= LEFT as i64
                        && x <= (W - RIGHT) as i64
                        && y >= TOP as i64
                        && y <= (H - BOTTOM) as i64
                };
                for i in 0..steps {
                    let (a, b) = (at(i), at(i + 1));
                    if inside(a) && inside(b) {
                        c.line(a, b, s.color, 1);
                    }
                }
            }
        }
        for &(x, y) in &p {
            c.rect(x - 4, y - 4, x + 4, y + 4, s.color);
        }
        for (label, &(x, y)) in s.labels.iter().zip(&p) {
            c.text(x + 7, y - 12, label, 1, s.color, false);
        }
    }
    // Labels, title, legend.
    c.text(
        l + (r - l - text_width(&plot.x_label, 2)) / 2,
        b + 40,
        &plot.x_label,
        2,
        black,
        false,
    );
    c.text(
        16,
        t + (b - t + text_width(&plot.y_label, 2)) / 2,
        &plot.y_label,
        2,
        black,
        true,
    );
    c.text(
        l + (r - l - text_width(&plot.title, 2)) / 2,
        14,
        &plot.title,
        2,
        black,
        false,
    );
    for (k, s) in plot.series.iter().enumerate() {
        let y = t + 10 + 26 * k as i64;
        c.rect(r + 20, y + 2, r + 32, y + 14, s.color);
        c.text(r + 40, y, &s.name, 2, black, false);
    }
    Ok(c.px)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pixel(px: &[u8], (x, y): (i64, i64)) -> [u8; 3] {
        let o = 3 * (y as usize * W + x as usize);
        [px[o], px[o + 1], px[o + 2]]
    }

    #[test]
    fn fitted_lines_and_point_labels_are_drawn() {
        let colour = PALETTE[1];
        let points = vec![(10.0, 1.0), (100.0, 10.0), (1000.0, 100.0)];
        let plot = |fit, labels| Plot {
            title: "t".into(),
            x_label: "x".into(),
            y_label: "y".into(),
            series: vec![Series {
                name: "s".into(),
                color: colour,
                points: points.clone(),
                lines: false,
                labels,
                fit,
            }],
        };
        let bare = render(&plot(None, Vec::new())).unwrap();
        let drawn = render(&plot(Some((1.0, 0.1f64.ln())), vec!["121".into(); 3])).unwrap();
        // y = 0.1 x passes through the points: halfway between the first two (in log space) the fitted
        // line is drawn, and nothing is there without it.
        let (xa, xb, ya, yb) = (1.0, 3.0, 0.0, 2.0);
        let (pw, ph) = ((W - LEFT - RIGHT) as f64, (H - TOP - BOTTOM) as f64);
        let to_px = |x: f64, y: f64| {
            (
                LEFT as i64 + ((x.log10() - xa) / (xb - xa) * pw).round() as i64,
                (H - BOTTOM) as i64 - ((y.log10() - ya) / (yb - ya) * ph).round() as i64,
            )
        };
        let mid = to_px(10f64.powf(1.5), 10f64.powf(0.5));
        let near = |px: &[u8]| (-2..=2).any(|d| pixel(px, (mid.0, mid.1 + d)) == colour);
        assert!(near(&drawn) && !near(&bare));
        // The labels add pixels of the series' colour to the right of each point.
        let count = |px: &[u8]| px.chunks(3).filter(|p| *p == colour).count();
        assert!(count(&drawn) > count(&bare) + 3 * 20);
    }
}
