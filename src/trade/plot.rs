//! The bench's plots (plotters, drawn into memory and written as PNG with `image`): PSNR
//! against cost per scene group with the Pareto front, and the light x speed map of the winners.
//!
//! Text needs a TrueType font: the first of `NEUSPIKE_FONT` and the usual system paths of DejaVu
//! Sans or Liberation Sans that loads. Without one the plots are drawn without text (a warning
//! says so) and `summary.md` carries the numbers.

use std::path::Path;
use std::sync::OnceLock;

use eyre::{WrapErr, eyre};
use plotters::prelude::*;

use super::table::{self, Row};

/// Font paths tried after `NEUSPIKE_FONT`.
const FONTS: [&str; 5] = [
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
    "/usr/share/fonts/liberation-sans/LiberationSans-Regular.ttf",
];

/// Registers a font as `sans-serif` once; whether text can be drawn.
pub(crate) fn has_font() -> bool {
    static FONT: OnceLock<bool> = OnceLock::new();
    *FONT.get_or_init(|| {
        let env = std::env::var("NEUSPIKE_FONT").ok();
        for path in env.iter().map(String::as_str).chain(FONTS) {
            if let Ok(bytes) = std::fs::read(path) {
                // Leaked once: plotters keeps fonts for the life of the process.
                let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
                if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                    return true;
                }
            }
        }
        tracing::warn!(
            "no TrueType font found (set NEUSPIKE_FONT to a .ttf file): plots are drawn without text"
        );
        false
    })
}

pub(crate) fn pe<E: std::fmt::Display>(e: E) -> eyre::Report {
    eyre!("plot: {e}")
}

/// A colour per method, stable across plots (by its place in the first-seen order).
pub(crate) fn colour(i: usize) -> RGBColor {
    const C: [RGBColor; 16] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(44, 160, 44),
        RGBColor(214, 39, 40),
        RGBColor(148, 103, 189),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(127, 127, 127),
        RGBColor(188, 189, 34),
        RGBColor(23, 190, 207),
        RGBColor(0, 0, 0),
        RGBColor(174, 199, 232),
        RGBColor(255, 187, 120),
        RGBColor(152, 223, 138),
        RGBColor(255, 152, 150),
        RGBColor(197, 176, 213),
    ];
    C[i % C.len()]
}

pub(crate) fn save(buf: Vec<u8>, (w, h): (u32, u32), path: &Path) -> eyre::Result<()> {
    let img = image::RgbImage::from_raw(w, h, buf).ok_or_else(|| eyre!("plot: buffer size"))?;
    img.save(path)
        .wrap_err_with(|| format!("cannot write {}", path.display()))
}

/// `pareto.png`: per scene group, each method's mean PSNR against its median cost on one thread
/// (log scale), the Pareto front joined by a line.
///
/// # Errors
/// Drawing or writing failed.
pub fn pareto(rows: &[Row], path: &Path) -> eyre::Result<()> {
    let text = has_font();
    let scored: Vec<Row> = rows
        .iter()
        .filter(|r| r.psnr.is_finite())
        .cloned()
        .collect();
    let groups = table::by(&scored, |r| r.group.clone());
    let mut names: Vec<String> = Vec::new();
    for r in rows {
        if !names.contains(&r.method) {
            names.push(r.method.clone());
        }
    }
    let cols = 4usize;
    let n = groups.len().max(1);
    let rows_n = n.div_ceil(cols);
    let (w, h) = (1600u32, 380 * rows_n as u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        let areas = root.split_evenly((rows_n, cols));
        for (area, (g, methods)) in areas.iter().zip(&groups) {
            let pts: Vec<(String, f64, f64)> = methods
                .iter()
                .map(|(m, rs)| {
                    let s = table::summarise(rs);
                    (m.clone(), s.p50_1t_ms, s.psnr)
                })
                .filter(|(_, c, p)| c.is_finite() && *c > 0.0 && p.is_finite())
                .collect();
            if pts.is_empty() {
                continue;
            }
            let (cmin, cmax) = pts
                .iter()
                .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
            let (pmin, pmax) = pts
                .iter()
                .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.2), b.max(p.2)));
            let mut builder = ChartBuilder::on(area);
            builder.margin(10);
            if text {
                builder
                    .caption(g, ("sans-serif", 18))
                    .x_label_area_size(32)
                    .y_label_area_size(44);
            }
            let mut chart = builder
                .build_cartesian_2d(
                    (cmin / 1.5..cmax * 3.0).log_scale(),
                    (pmin - 1.0)..(pmax + 1.0),
                )
                .map_err(pe)?;
            let mut mesh = chart.configure_mesh();
            if text {
                mesh.x_desc("ms a frame, 1 thread").y_desc("PSNR dB");
            } else {
                mesh.x_labels(0).y_labels(0);
            }
            mesh.draw().map_err(pe)?;
            let front = table::pareto(&pts);
            chart
                .draw_series(LineSeries::new(
                    front.iter().map(|(_, c, p)| (*c, *p)),
                    BLACK.stroke_width(2),
                ))
                .map_err(pe)?;
            for (m, c, p) in &pts {
                let i = names.iter().position(|x| x == m).unwrap_or(0);
                chart
                    .draw_series(std::iter::once(Circle::new(
                        (*c, *p),
                        5,
                        colour(i).filled(),
                    )))
                    .map_err(pe)?;
                if text {
                    chart
                        .draw_series(std::iter::once(Text::new(
                            m.trim_start_matches("neuspike-").to_string(),
                            (*c * 1.08, *p),
                            ("sans-serif", 12).into_font().color(&colour(i)),
                        )))
                        .map_err(pe)?;
                }
            }
        }
        root.present().map_err(pe)?;
    }
    save(buf, (w, h), path)
}

/// `winners.png`: the light x speed grid, each cell coloured by its best method (mean PSNR) and
/// labelled with it and its PSNR.
///
/// # Errors
/// Drawing or writing failed.
pub fn winners(rows: &[Row], path: &Path) -> eyre::Result<()> {
    let text = has_font();
    let cells: Vec<Row> = rows
        .iter()
        .filter(|r| {
            r.class.starts_with("light") && r.psnr.is_finite() && !super::auto::is_auto(&r.method)
        })
        .cloned()
        .collect();
    let mut lights: Vec<f64> = cells.iter().map(|r| r.light).collect();
    let mut speeds: Vec<f64> = cells.iter().map(|r| r.speed_px_s).collect();
    for v in [&mut lights, &mut speeds] {
        v.sort_by(f64::total_cmp);
        v.dedup();
    }
    let mut names: Vec<String> = Vec::new();
    for r in rows {
        if !names.contains(&r.method) {
            names.push(r.method.clone());
        }
    }
    let by_class = table::by(&cells, |r| r.class.clone());
    let (w, h) = (900u32, 640u32);
    let mut buf = vec![0u8; (w * h * 3) as usize];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (w, h)).into_drawing_area();
        root.fill(&WHITE).map_err(pe)?;
        let (nx, ny) = (speeds.len().max(1), lights.len().max(1));
        let mut builder = ChartBuilder::on(&root);
        builder.margin(16);
        if text {
            builder
                .caption(
                    "best method (mean PSNR dB) per light and speed",
                    ("sans-serif", 20),
                )
                .x_label_area_size(40)
                .y_label_area_size(60);
        }
        let mut chart = builder
            .build_cartesian_2d(0f64..nx as f64, 0f64..ny as f64)
            .map_err(pe)?;
        let mut mesh = chart.configure_mesh();
        mesh.disable_mesh();
        if text {
            let fx = |x: &f64| label_at(&speeds, *x);
            let fy = |y: &f64| label_at(&lights, *y);
            mesh.x_desc("speed, px/s")
                .y_desc("light scale")
                .x_labels(nx * 2 + 1)
                .y_labels(ny * 2 + 1)
                .x_label_formatter(&fx)
                .y_label_formatter(&fy);
            mesh.draw().map_err(pe)?;
        }
        for (j, l) in lights.iter().enumerate() {
            for (i, s) in speeds.iter().enumerate() {
                let name = super::grid::SceneClass::cell(*l, *s).name;
                let Some(methods) = by_class.get(&name) else {
                    continue;
                };
                let per: Vec<(String, table::Summary)> = methods
                    .iter()
                    .map(|(m, rs)| (m.clone(), table::summarise(rs)))
                    .collect();
                let Some((best, _)) = table::choice(&per, 0.0) else {
                    continue;
                };
                let psnr = per
                    .iter()
                    .find(|(m, _)| *m == best)
                    .map_or(f64::NAN, |(_, s)| s.psnr);
                let k = names.iter().position(|x| *x == best).unwrap_or(0);
                let (x, y) = (i as f64, j as f64);
                chart
                    .draw_series(std::iter::once(Rectangle::new(
                        [(x + 0.02, y + 0.02), (x + 0.98, y + 0.98)],
                        colour(k).mix(0.55).filled(),
                    )))
                    .map_err(pe)?;
                if text {
                    chart
                        .draw_series([
                            Text::new(
                                best.trim_start_matches("neuspike-").to_string(),
                                (x + 0.08, y + 0.62),
                                ("sans-serif", 16).into_font(),
                            ),
                            Text::new(
                                format!("{psnr:.1} dB"),
                                (x + 0.08, y + 0.38),
                                ("sans-serif", 14).into_font(),
                            ),
                        ])
                        .map_err(pe)?;
                }
            }
        }
        root.present().map_err(pe)?;
    }
    save(buf, (w, h), path)
}

/// The axis label at coordinate `x`: the value of the cell whose centre it is, else nothing.
fn label_at(values: &[f64], x: f64) -> String {
    let i = x - 0.5;
    if (i - i.round()).abs() < 1e-6 && i >= 0.0 {
        values
            .get(i.round() as usize)
            .map_or(String::new(), |v| format!("{v}"))
    } else {
        String::new()
    }
}
