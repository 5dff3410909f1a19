//! A small PNG line chart of reconstruction error against subdivision level (log scale), drawn
//! directly into pixels with a 5×7 bitmap font: no plotting dependency for one figure.

use crate::maps::reconstruct::Distances;

const W: usize = 640;
const H: usize = 400;
const LEFT: usize = 70;
const RIGHT: usize = 20;
const TOP: usize = 20;
const BOTTOM: usize = 50;

/// 5×7 glyphs, one row per byte (bit 4 = leftmost column).
fn glyph(c: char) -> [u8; 7] {
    match c {
        '0' => [14, 17, 19, 21, 25, 17, 14],
        '1' => [4, 12, 4, 4, 4, 4, 14],
        '2' => [14, 17, 1, 2, 4, 8, 31],
        '3' => [31, 2, 4, 2, 1, 17, 14],
        '4' => [2, 6, 10, 18, 31, 2, 2],
        '5' => [31, 16, 30, 1, 1, 17, 14],
        '6' => [6, 8, 16, 30, 17, 17, 14],
        '7' => [31, 1, 2, 4, 8, 8, 8],
        '8' => [14, 17, 17, 14, 17, 17, 14],
        '9' => [14, 17, 17, 15, 1, 2, 12],
        '.' => [0, 0, 0, 0, 0, 12, 12],
        '%' => [24, 25, 2, 4, 8, 19, 3],
        '-' => [0, 0, 0, 31, 0, 0, 0],
        '>' => [8, 4, 2, 1, 2, 4, 8],
        '<' => [2, 4, 8, 16, 8, 4, 2],
        'A' => [14, 17, 17, 31, 17, 17, 17],
        'M' => [17, 27, 21, 21, 17, 17, 17],
        'R' => [30, 17, 17, 30, 20, 18, 17],
        'S' => [15, 16, 16, 14, 1, 1, 30],
        'X' => [17, 17, 10, 4, 10, 17, 17],
        'a' => [0, 0, 14, 1, 15, 17, 15],
        'd' => [1, 1, 13, 19, 17, 17, 15],
        'e' => [0, 0, 14, 17, 31, 16, 14],
        'g' => [0, 15, 17, 17, 15, 1, 14],
        'i' => [4, 0, 12, 4, 4, 4, 14],
        'l' => [12, 4, 4, 4, 4, 4, 14],
        'v' => [0, 0, 17, 17, 17, 10, 4],
        _ => [0; 7],
    }
}

struct Canvas {
    rgb: Vec<u8>,
}

impl Canvas {
    fn set(&mut self, x: i64, y: i64, c: [u8; 3]) {
        if x >= 0 && y >= 0 && (x as usize) < W && (y as usize) < H {
            let i = 3 * (y as usize * W + x as usize);
            self.rgb[i..i + 3].copy_from_slice(&c);
        }
    }
    fn line(&mut self, (x0, y0): (f64, f64), (x1, y1): (f64, f64), c: [u8; 3], width: i64) {
        let steps = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as i64).max(1);
        for s in 0..=steps {
            let t = s as f64 / steps as f64;
            let (x, y) = ((x0 + t * (x1 - x0)).round() as i64, (y0 + t * (y1 - y0)).round() as i64);
            for dx in -(width / 2)..=(width / 2) {
                for dy in -(width / 2)..=(width / 2) {
                    self.set(x + dx, y + dy, c);
                }
            }
        }
    }
    fn text(&mut self, x: i64, y: i64, s: &str, c: [u8; 3]) {
        for (k, ch) in s.chars().enumerate() {
            let g = glyph(ch);
            for (row, bits) in g.iter().enumerate() {
                for col in 0..5 {
                    if bits & (16 >> col) != 0 {
                        self.set(x + 6 * k as i64 + col, y + row as i64, c);
                    }
                }
            }
        }
    }
}

/// The four error curves (fractions of the diagonal, shown in %) against level, as a PNG.
pub fn error_plot(table: &[Distances]) -> Vec<u8> {
    let mut cv = Canvas { rgb: vec![255; W * H * 3] };
    let (x0, x1) = (LEFT as f64, (W - RIGHT) as f64);
    let (y0, y1) = (TOP as f64, (H - BOTTOM) as f64);
    let max_level = table.iter().map(|d| d.level).max().unwrap_or(1).max(1) as f64;
    // Decades of % from 1e-4 % to 100 %.
    let (lo, hi) = (-4.0f64, 2.0f64);
    let px = |level: f64| x0 + (x1 - x0) * level / max_level;
    let py = |frac: f64| {
        let pct = (frac * 100.0).max(1e-12).log10().clamp(lo, hi);
        y1 - (y1 - y0) * (pct - lo) / (hi - lo)
    };
    let grey = [200, 200, 200];
    let black = [0, 0, 0];
    for k in 0..=((hi - lo) as i64) {
        let y = y1 - (y1 - y0) * k as f64 / (hi - lo);
        cv.line((x0, y), (x1, y), grey, 1);
        let label = match lo as i64 + k {
            e if e >= 0 => format!("{}%", 10i64.pow(e as u32)),
            e => format!("{}%", format!("{:.*}", (-e) as usize, 10f64.powi(e as i32))),
        };
        cv.text(x0 as i64 - 8 - 6 * label.len() as i64, y as i64 - 3, &label, black);
    }
    for l in 0..=max_level as i64 {
        let x = px(l as f64);
        cv.line((x, y0), (x, y1), grey, 1);
        cv.text(x as i64 - 2, y1 as i64 + 8, &l.to_string(), black);
    }
    cv.line((x0, y0), (x0, y1), black, 1);
    cv.line((x0, y1), (x1, y1), black, 1);
    cv.text(((x0 + x1) / 2.0) as i64 - 15, H as i64 - 20, "level", black);
    let series: [(&str, [u8; 3], fn(&Distances) -> f64); 4] = [
        ("RMS ->", [31, 119, 180], |d| d.rms_to_scan),
        ("MAX ->", [140, 190, 230], |d| d.hausdorff_to_scan),
        ("RMS <-", [214, 39, 40], |d| d.rms_from_scan),
        ("MAX <-", [240, 150, 150], |d| d.hausdorff_from_scan),
    ];
    for (k, (name, color, f)) in series.iter().enumerate() {
        for w in table.windows(2) {
            cv.line((px(w[0].level as f64), py(f(&w[0]))), (px(w[1].level as f64), py(f(&w[1]))), *color, 3);
        }
        for d in table {
            let (x, y) = (px(d.level as f64), py(f(d)));
            for dx in -3..=3 {
                for dy in -3..=3 {
                    cv.set(x as i64 + dx, y as i64 + dy, *color);
                }
            }
        }
        let (lx, ly) = (x1 as i64 - 110, y0 as i64 + 8 + 14 * k as i64);
        cv.line((lx as f64, ly as f64 + 3.0), (lx as f64 + 24.0, ly as f64 + 3.0), *color, 3);
        cv.text(lx + 32, ly, name, black);
    }
    cv.text(8, 6, "% diag", black);
    let mut out = Vec::new();
    {
        let mut enc = png::Encoder::new(&mut out, W as u32, H as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.set_depth(png::BitDepth::Eight);
        let mut w = enc.write_header().expect("PNG header into memory");
        w.write_image_data(&cv.rgb).expect("PNG data into memory");
    }
    out
}
