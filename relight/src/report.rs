//! The run's report as JSON, and the error-against-time plot as a PNG (log10 relative
//! error over seconds, one colour per phase, decade grid lines, labelled axes drawn with a
//! built-in 3x5 pixel font so no font file is needed).

use std::path::Path;

use image::{Rgb, RgbImage};

use crate::error::{Error, Result};
use crate::pipeline::Report;

pub fn write_json(report: &Report, path: &Path) -> Result<()> {
    let text = serde_json::to_vec_pretty(report).map_err(|e| Error::Usage(format!("report: {e}")))?;
    q3gltf_convert::output::write_atomic(path, &text).map_err(|e| Error::Io { path: path.display().to_string(), source: e })
}

/// 3x5 glyphs, rows top to bottom, 3 bits each (MSB left).
fn glyph(c: char) -> [u8; 5] {
    match c {
        '0' => [7, 5, 5, 5, 7],
        '1' => [2, 6, 2, 2, 7],
        '2' => [7, 1, 7, 4, 7],
        '3' => [7, 1, 7, 1, 7],
        '4' => [5, 5, 7, 1, 1],
        '5' => [7, 4, 7, 1, 7],
        '6' => [7, 4, 7, 5, 7],
        '7' => [7, 1, 1, 1, 1],
        '8' => [7, 5, 7, 5, 7],
        '9' => [7, 5, 7, 1, 7],
        '.' => [0, 0, 0, 0, 2],
        '-' => [0, 0, 7, 0, 0],
        'e' => [7, 5, 7, 4, 7],
        'r' => [0, 6, 5, 4, 4],
        'o' => [0, 7, 5, 5, 7],
        't' => [2, 7, 2, 2, 3],
        'i' => [2, 0, 2, 2, 2],
        'm' => [0, 7, 7, 5, 5],
        's' => [0, 7, 6, 1, 7],
        'l' => [2, 2, 2, 2, 3],
        'g' => [7, 5, 7, 1, 7],
        '(' => [1, 2, 2, 2, 1],
        ')' => [4, 2, 2, 2, 4],
        _ => [0; 5],
    }
}

fn text(img: &mut RgbImage, x: i64, y: i64, s: &str, scale: i64, color: Rgb<u8>) {
    for (k, ch) in s.chars().enumerate() {
        let g = glyph(ch);
        for (row, bits) in g.iter().enumerate() {
            for col in 0..3 {
                if bits >> (2 - col) & 1 == 1 {
                    for dy in 0..scale {
                        for dx in 0..scale {
                            put(img, x + (k as i64 * 4 + col) * scale + dx, y + row as i64 * scale + dy, color);
                        }
                    }
                }
            }
        }
    }
}

fn put(img: &mut RgbImage, x: i64, y: i64, c: Rgb<u8>) {
    if x >= 0 && y >= 0 && (x as u32) < img.width() && (y as u32) < img.height() {
        img.put_pixel(x as u32, y as u32, c);
    }
}

fn line(img: &mut RgbImage, (x0, y0): (f64, f64), (x1, y1): (f64, f64), c: Rgb<u8>) {
    let n = ((x1 - x0).abs().max((y1 - y0).abs()).ceil() as i64).clamp(1, 10_000);
    for i in 0..=n {
        let t = i as f64 / n as f64;
        let (x, y) = (x0 + (x1 - x0) * t, y0 + (y1 - y0) * t);
        put(img, x.round() as i64, y.round() as i64, c);
        put(img, x.round() as i64, y.round() as i64 + 1, c);
    }
}

pub fn write_plot(report: &Report, path: &Path) -> Result<()> {
    let (w, h) = (900u32, 540u32);
    let (left, right, top, bottom) = (70.0, 20.0, 20.0, 50.0);
    let mut img = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    let pts: Vec<(f64, f64, usize)> = report.iterations.iter().filter(|r| r.rel_error.is_finite() && r.rel_error > 0.0).map(|r| (r.time_s, r.rel_error.log10(), r.phase)).collect();
    let t_max = pts.iter().map(|p| p.0).fold(1e-3, f64::max);
    let (mut e_lo, mut e_hi) = pts.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.1), b.max(p.1)));
    if !e_lo.is_finite() {
        (e_lo, e_hi) = (-2.0, 0.0);
    }
    let (e_lo, e_hi) = (e_lo.floor(), e_hi.ceil().max(e_lo.floor() + 1.0));
    let pw = w as f64 - left - right;
    let ph = h as f64 - top - bottom;
    let sx = |t: f64| left + t / t_max * pw;
    let sy = |e: f64| top + (e_hi - e) / (e_hi - e_lo) * ph;
    let grey = Rgb([210, 210, 210]);
    let black = Rgb([0, 0, 0]);
    let mut d = e_lo;
    while d <= e_hi + 1e-9 {
        line(&mut img, (left, sy(d)), (left + pw, sy(d)), grey);
        text(&mut img, 8, sy(d) as i64 - 5, &format!("1e{}", d as i64), 2, black);
        d += 1.0;
    }
    for k in 0..=5 {
        let t = t_max * k as f64 / 5.0;
        line(&mut img, (sx(t), top), (sx(t), top + ph), grey);
        // Enough decimals that the ticks differ (a small scene optimises in milliseconds).
        let decimals = (1.0 - (t_max / 5.0).log10().floor()).clamp(0.0, 4.0) as usize;
        text(&mut img, sx(t) as i64 - 10, (top + ph) as i64 + 8, &format!("{t:.decimals$}"), 2, black);
    }
    line(&mut img, (left, top), (left, top + ph), black);
    line(&mut img, (left, top + ph), (left + pw, top + ph), black);
    text(&mut img, (left + pw / 2.0) as i64 - 30, h as i64 - 18, "time (s)", 2, black);
    text(&mut img, 8, 2, "rel error", 2, black);
    let palette = [Rgb([31, 119, 180]), Rgb([255, 127, 14]), Rgb([44, 160, 44]), Rgb([214, 39, 40]), Rgb([148, 103, 189]), Rgb([140, 86, 75])];
    for win in pts.windows(2) {
        let c = palette[win[1].2 % palette.len()];
        line(&mut img, (sx(win[0].0), sy(win[0].1)), (sx(win[1].0), sy(win[1].1)), c);
    }
    let mut bytes = Vec::new();
    image::DynamicImage::ImageRgb8(img)
        .write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png)
        .map_err(|e| Error::Usage(format!("plot: {e}")))?;
    q3gltf_convert::output::write_atomic(path, &bytes).map_err(|e| Error::Io { path: path.display().to_string(), source: e })
}
