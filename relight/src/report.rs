//! The run's report as JSON, and the error-against-time plot as a PNG: relative error on
//! a log axis (decades labelled 10 with a raised exponent) over the run's seconds, one
//! colour per optimiser phase with a legend, the stages that took a noticeable share of
//! the time marked where they end, and a title with the map, the settings and the result.
//! Text is drawn with a built-in 3x5 pixel font (capitals, digits, punctuation), so no
//! font file is needed.

use std::path::Path;

use image::{Rgb, RgbImage};

use crate::error::{Error, Result};
use crate::pipeline::Report;

/// The report as JSON, with the bake of the output under `bake` when there was one
/// (`relight --bake`).
pub fn write_json(report: &Report, bake: Option<&crate::bake::Report>, path: &Path) -> Result<()> {
    let bad = |e: serde_json::Error| Error::Usage(format!("report: {e}"));
    let mut json = serde_json::to_value(report).map_err(bad)?;
    if let (Some(b), Some(o)) = (bake, json.as_object_mut()) {
        o.insert("bake".into(), serde_json::to_value(b).map_err(bad)?);
    }
    let text = serde_json::to_vec_pretty(&json).map_err(bad)?;
    q3gltf_convert::output::write_atomic(path, &text).map_err(|e| Error::Io { path: path.display().to_string(), source: e })
}

/// 3x5 glyphs, rows top to bottom, 3 bits each (MSB left); letters are capitals (text is
/// drawn upper-cased). `None`: no glyph (drawn as a box, so a gap never hides a character).
fn glyph(c: char) -> Option<[u8; 5]> {
    Some(match c.to_ascii_uppercase() {
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
        'A' => [2, 5, 7, 5, 5],
        'B' => [6, 5, 6, 5, 6],
        'C' => [3, 4, 4, 4, 3],
        'D' => [6, 5, 5, 5, 6],
        'E' => [7, 4, 6, 4, 7],
        'F' => [7, 4, 6, 4, 4],
        'G' => [3, 4, 5, 5, 3],
        'H' => [5, 5, 7, 5, 5],
        'I' => [7, 2, 2, 2, 7],
        'J' => [1, 1, 1, 5, 2],
        'K' => [5, 5, 6, 5, 5],
        'L' => [4, 4, 4, 4, 7],
        'M' => [5, 7, 7, 5, 5],
        'N' => [6, 5, 5, 5, 5],
        'O' => [2, 5, 5, 5, 2],
        'P' => [6, 5, 6, 4, 4],
        'Q' => [2, 5, 5, 6, 3],
        'R' => [6, 5, 6, 5, 5],
        'S' => [3, 4, 2, 1, 6],
        'T' => [7, 2, 2, 2, 2],
        'U' => [5, 5, 5, 5, 7],
        'V' => [5, 5, 5, 5, 2],
        'W' => [5, 5, 7, 7, 5],
        'X' => [5, 5, 2, 5, 5],
        'Y' => [5, 5, 2, 2, 2],
        'Z' => [7, 1, 2, 4, 7],
        ' ' => [0, 0, 0, 0, 0],
        '.' => [0, 0, 0, 0, 2],
        ',' => [0, 0, 0, 2, 6],
        ':' => [0, 2, 0, 2, 0],
        ';' => [0, 2, 0, 2, 4],
        '-' => [0, 0, 7, 0, 0],
        '+' => [0, 2, 7, 2, 0],
        '=' => [0, 7, 0, 7, 0],
        '_' => [0, 0, 0, 0, 7],
        '/' => [1, 1, 2, 4, 4],
        '%' => [5, 1, 2, 4, 5],
        '>' => [4, 2, 1, 2, 4],
        '<' => [1, 2, 4, 2, 1],
        '(' => [1, 2, 2, 2, 1],
        ')' => [4, 2, 2, 2, 4],
        '[' => [3, 2, 2, 2, 3],
        ']' => [6, 2, 2, 2, 6],
        '#' => [5, 7, 5, 7, 5],
        '*' => [0, 5, 2, 5, 0],
        '\'' => [2, 2, 0, 0, 0],
        _ => return None,
    })
}

/// Draws `s` at `(x, y)` (top left), `scale` pixels per font pixel; returns its width.
fn text(img: &mut RgbImage, x: i64, y: i64, s: &str, scale: i64, color: Rgb<u8>) -> i64 {
    for (k, ch) in s.chars().enumerate() {
        let g = glyph(ch).unwrap_or([7, 5, 5, 5, 7]);
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
    text_width(s, scale)
}

fn text_width(s: &str, scale: i64) -> i64 {
    (s.chars().count() as i64 * 4 - 1).max(0) * scale
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

fn fill(img: &mut RgbImage, x: i64, y: i64, w: i64, h: i64, c: Rgb<u8>) {
    for yy in y..y + h {
        for xx in x..x + w {
            put(img, xx, yy, c);
        }
    }
}

/// One colour per phase of the fit (cycled).
pub const PHASE_COLORS: [Rgb<u8>; 6] = [Rgb([31, 119, 180]), Rgb([255, 127, 14]), Rgb([44, 160, 44]), Rgb([214, 39, 40]), Rgb([148, 103, 189]), Rgb([140, 86, 75])];
/// The greedy placement's iterations.
pub const PLACEMENT_COLOR: Rgb<u8> = Rgb([150, 150, 150]);

/// The plot as an image (see the module docs).
pub fn plot(report: &Report) -> RgbImage {
    let (w, h) = (960u32, 600u32);
    let (left, right, top, bottom) = (80.0, 24.0, 64.0, 50.0);
    let mut img = RgbImage::from_pixel(w, h, Rgb([255, 255, 255]));
    // (time, log10 error, series): the placement's iterations are one series (grey), the
    // fit's phases one each.
    let pts: Vec<(f64, f64, Option<usize>)> = report
        .iterations
        .iter()
        .filter(|r| r.rel_error.is_finite() && r.rel_error > 0.0 && r.time_s.is_finite())
        .map(|r| (r.time_s, r.rel_error.log10(), (!r.placement).then_some(r.phase)))
        .collect();
    let color = |series: Option<usize>| series.map_or(PLACEMENT_COLOR, |k| PHASE_COLORS[k % PHASE_COLORS.len()]);
    // The whole run on the time axis: the stages after the last iteration show where the
    // rest of the time went.
    let t_max = pts.iter().map(|p| p.0).fold(report.total_time_s.max(1e-3), f64::max);
    let (mut e_lo, mut e_hi) = pts.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), p| (a.min(p.1), b.max(p.1)));
    if !e_lo.is_finite() {
        (e_lo, e_hi) = (-2.0, 0.0);
    }
    let (e_lo, e_hi) = (e_lo.floor(), e_hi.ceil().max(e_lo.floor() + 1.0));
    let pw = w as f64 - left - right;
    let ph = h as f64 - top - bottom;
    let sx = |t: f64| left + t / t_max * pw;
    let sy = |e: f64| top + (e_hi - e) / (e_hi - e_lo) * ph;
    let grey = Rgb([215, 215, 215]);
    let dark = Rgb([110, 110, 110]);
    let black = Rgb([0, 0, 0]);

    // Title: the map and settings, then the result.
    let stem = Path::new(&report.input).file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    let backend = report.backend.split(" (").next().unwrap_or("");
    text(&mut img, 12, 8, &format!("{stem}: scheme {}, init {}, {:?} target, {backend}", report.scheme, report.init, report.target_space), 2, black);
    text(
        &mut img,
        12,
        28,
        &format!("relative error {:.4} -> {:.4}, {} lights, {:.1} s", report.rel_error_initial, report.rel_error_final, report.lights.len(), report.total_time_s),
        2,
        dark,
    );

    // Decades: 10 with the exponent raised.
    let mut d = e_lo;
    while d <= e_hi + 1e-9 {
        line(&mut img, (left, sy(d)), (left + pw, sy(d)), grey);
        let y = sy(d) as i64 - 5;
        let x = text(&mut img, 14, y, "10", 2, black);
        text(&mut img, 14 + x + 3, y - 6, &format!("{}", d as i64), 2, black);
        d += 1.0;
    }
    // Time ticks, with enough decimals that they differ (a small scene optimises in ms).
    for k in 0..=5 {
        let t = t_max * k as f64 / 5.0;
        line(&mut img, (sx(t), top), (sx(t), top + ph), grey);
        let decimals = (1.0 - (t_max / 5.0).log10().floor()).clamp(0.0, 4.0) as usize;
        let label = format!("{t:.decimals$}");
        text(&mut img, sx(t) as i64 - text_width(&label, 2) / 2, (top + ph) as i64 + 8, &label, 2, black);
    }
    // Stages that took at least 8% of the run, marked where they end.
    let mut at = 0.0;
    let mut row = 0;
    for (name, s) in &report.stage_times_s {
        at += s;
        if *s >= 0.08 * report.total_time_s && at <= t_max * 1.0001 {
            let x = sx(at);
            let mut y = top;
            while y < top + ph {
                line(&mut img, (x, y), (x, (y + 4.0).min(top + ph)), dark);
                y += 9.0;
            }
            let label = format!("{name} {s:.1}s");
            let tw = text_width(&label, 2);
            text(&mut img, (x as i64 - tw - 4).max(left as i64 + 4), (top + ph) as i64 - 16 - 16 * (row % 3), &label, 2, dark);
            row += 1;
        }
    }
    line(&mut img, (left, top), (left, top + ph), black);
    line(&mut img, (left, top + ph), (left + pw, top + ph), black);
    let xl = "time (s)";
    text(&mut img, (left + pw / 2.0) as i64 - text_width(xl, 2) / 2, h as i64 - 18, xl, 2, black);
    text(&mut img, left as i64 + 6, top as i64 - 14, "relative error (log)", 2, black);
    for win in pts.windows(2) {
        line(&mut img, (sx(win[0].0), sy(win[0].1)), (sx(win[1].0), sy(win[1].1)), color(win[1].2));
    }

    // Legend: the phases that have iterations, in order.
    let mut shown: Vec<(Option<usize>, String)> = Vec::new();
    for p in &pts {
        if !shown.iter().any(|(k, _)| *k == p.2) {
            let name = match p.2 {
                None => "placement (subsample)".to_string(),
                Some(k) => report.phases.get(k).map_or_else(|| format!("phase {}", k + 1), |ph| ph.name.clone()),
            };
            shown.push((p.2, name));
        }
    }
    if !shown.is_empty() {
        let bw = shown.iter().map(|(_, n)| text_width(n, 2)).max().unwrap_or(0) + 40;
        let bh = 16 * shown.len() as i64 + 8;
        let (bx, by) = ((left + pw) as i64 - bw - 8, top as i64 + 8);
        fill(&mut img, bx, by, bw, bh, Rgb([255, 255, 255]));
        for (k, (phase, name)) in shown.iter().enumerate() {
            let y = by + 6 + 16 * k as i64;
            fill(&mut img, bx + 6, y + 3, 20, 4, color(*phase));
            text(&mut img, bx + 32, y, name, 2, black);
        }
    }
    img
}

pub fn write_plot(report: &Report, path: &Path) -> Result<()> {
    let mut bytes = Vec::new();
    image::DynamicImage::ImageRgb8(plot(report))
        .write_to(&mut std::io::Cursor::new(&mut bytes), image::ImageFormat::Png)
        .map_err(|e| Error::Usage(format!("plot: {e}")))?;
    q3gltf_convert::output::write_atomic(path, &bytes).map_err(|e| Error::Io { path: path.display().to_string(), source: e })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_character_of_a_plots_text_has_a_glyph() {
        let names = "adam lbfgs positions intensities all globals sun sky surfaces ambient prune merge polish";
        let chars = "abcdefghijklmnopqrstuvwxyz0123456789 .,:;-+=_/%><()[]#*'";
        for c in chars.chars().chain(names.chars()) {
            assert!(glyph(c).is_some(), "no glyph for {c:?}");
        }
        // Distinct glyphs for distinct characters (no two letters drawn alike).
        let mut seen = std::collections::HashMap::new();
        for c in "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789".chars() {
            if let Some(other) = seen.insert(glyph(c).unwrap(), c) {
                // 0 and O, 5 and S share shapes in 3x5 fonts only if drawn alike: they are not here.
                panic!("{c} and {other} are drawn alike");
            }
        }
        assert_eq!(text_width("ab", 2), 14);
    }
}
