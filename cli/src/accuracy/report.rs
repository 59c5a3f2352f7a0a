//! The report folder: `index.html` (one self-contained page, plots as inline SVG),
//! `report.json` and the compared images as PNG. The folder is written whole into a sibling
//! temporary folder and renamed into place, so a failed run leaves no partial report, and
//! only a folder that holds a previous report (or nothing) is ever replaced.

use std::fmt::Write as _;
use std::path::{Component, Path, PathBuf};

use super::pareto::{fmt_count, fmt_num};
use super::{AccuracyReport, ImageFile, KnobGroup, Point};
use vkrt::gpu::GpuError;
use vkrt::render::output::png_bytes;

mod plot;
pub use plot::plot_svg;

/// The file whose presence marks a folder as a previous report, safe to replace.
const MARKER: &str = "report.json";

fn io_error(path: &Path, reason: impl std::fmt::Display) -> GpuError {
    GpuError::Io {
        path: path.display().to_string(),
        reason: reason.to_string(),
    }
}

/// Writes the report into `dir`: `index.html`, `report.json` and every image as PNG under
/// its `file` name. `dir` may be missing, empty, or a previous report (it is replaced);
/// anything else there is refused and left untouched.
pub fn write(dir: &Path, report: &AccuracyReport, images: &[ImageFile]) -> Result<(), GpuError> {
    let (name, parent) = target(dir)?;
    let previous = check_replaceable(dir)?;
    let sibling = |what: &str| parent.join(format!("{name}.{what}-{}", std::process::id()));
    let tmp = sibling("tmp");
    if tmp.exists() {
        std::fs::remove_dir_all(&tmp).map_err(|e| io_error(&tmp, e))?;
    }
    let written = write_all(&tmp, report, images).and_then(|()| {
        if !previous {
            return std::fs::rename(&tmp, dir).map_err(|e| io_error(dir, e));
        }
        // Swap through a second sibling: a failed swap puts the previous report back.
        let old = sibling("old");
        std::fs::rename(dir, &old).map_err(|e| io_error(dir, e))?;
        if let Err(e) = std::fs::rename(&tmp, dir) {
            let _ = std::fs::rename(&old, dir);
            return Err(io_error(dir, e));
        }
        std::fs::remove_dir_all(&old).map_err(|e| io_error(&old, e))
    });
    if written.is_err() {
        let _ = std::fs::remove_dir_all(&tmp);
    }
    written
}

/// Refuses, before a long run, a folder [`write()`] would refuse: a missing parent, a file, a
/// folder holding something other than a previous report.
pub fn check_target(dir: &Path) -> Result<(), GpuError> {
    target(dir)?;
    check_replaceable(dir).map(|_| ())
}

/// `dir`'s name and its existing parent folder.
fn target(dir: &Path) -> Result<(String, &Path), GpuError> {
    let name = dir
        .file_name()
        .ok_or_else(|| io_error(dir, "not a folder name"))?
        .to_string_lossy()
        .into_owned();
    let parent = match dir.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if !parent.is_dir() {
        return Err(io_error(
            dir,
            format!("the parent folder {} does not exist", parent.display()),
        ));
    }
    Ok((name, parent))
}

/// Whether `dir` exists and must be replaced; an error if it is not ours to replace.
fn check_replaceable(dir: &Path) -> Result<bool, GpuError> {
    let Ok(meta) = std::fs::symlink_metadata(dir) else {
        return Ok(false);
    };
    if !meta.is_dir() {
        return Err(io_error(
            dir,
            "exists and is not a folder; refusing to replace it",
        ));
    }
    let mut entries = std::fs::read_dir(dir).map_err(|e| io_error(dir, e))?;
    if entries.next().is_some() && !dir.join(MARKER).is_file() {
        return Err(io_error(
            dir,
            format!("is a non-empty folder without {MARKER} (not a previous report); refusing to replace it"),
        ));
    }
    Ok(true)
}

fn write_all(tmp: &Path, report: &AccuracyReport, images: &[ImageFile]) -> Result<(), GpuError> {
    let put = |file: &str, bytes: &[u8]| -> Result<(), GpuError> {
        let path = inside(tmp, file)?;
        if let Some(p) = path.parent() {
            std::fs::create_dir_all(p).map_err(|e| io_error(p, e))?;
        }
        std::fs::write(&path, bytes).map_err(|e| io_error(&path, e))
    };
    std::fs::create_dir(tmp).map_err(|e| io_error(tmp, e))?;
    let json = serde_json::to_string_pretty(report).map_err(|e| io_error(Path::new(MARKER), e))?;
    put(MARKER, json.as_bytes())?;
    for im in images {
        let bytes = png_bytes(im.width, im.height, &im.rgba)
            .map_err(|e| io_error(Path::new(&im.file), e))?;
        put(&im.file, &bytes)?;
    }
    put("index.html", html(report).as_bytes())
}

/// `file` under `dir`, refusing names that would leave it (absolute, `..`).
fn inside(dir: &Path, file: &str) -> Result<PathBuf, GpuError> {
    let rel = Path::new(file);
    let plain = rel.components().all(|c| matches!(c, Component::Normal(_)));
    if !plain || file.is_empty() {
        return Err(io_error(
            rel,
            "not a plain relative file name in the report folder",
        ));
    }
    Ok(dir.join(rel))
}

/// `s` safe as HTML text or attribute value.
pub fn escape(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            c => out.push(c),
        }
    }
    out
}

const STYLE: &str = "
body{font:14px/1.45 system-ui,-apple-system,'Segoe UI',Roboto,sans-serif;margin:24px auto;max-width:1320px;padding:0 16px;color:#1d1d1f}
h1{margin:0 0 8px}h2{margin-top:36px;border-bottom:2px solid #ddd;padding-bottom:4px}h3{margin:20px 0 6px}
dl.meta{display:grid;grid-template-columns:max-content 1fr;gap:2px 16px;margin:0}dl.meta dt{color:#666}dl.meta dd{margin:0}
code{font:12px ui-monospace,monospace;background:#f3f3f3;padding:1px 4px;border-radius:3px;word-break:break-all}
.scroll{overflow-x:auto;margin:8px 0}
table{border-collapse:collapse;font-size:12.5px}th,td{padding:3px 8px;border-bottom:1px solid #e4e4e4;text-align:left;vertical-align:top}
th{background:#f6f6f6;position:sticky;top:0}td.n{text-align:right;font-variant-numeric:tabular-nums;white-space:nowrap}
tr.front td{font-weight:600;background:#eef5ff}td.imgs{white-space:nowrap;font-size:11.5px}td:first-child{min-width:9em}
.axes{color:#555;margin:2px 0 8px}.plot svg{max-width:100%;height:auto}
.figs{display:flex;flex-wrap:wrap;gap:10px}figure{margin:0;width:160px;font-size:11.5px}figure.ref{width:320px}
figure img{width:100%;image-rendering:pixelated;border:1px solid #ccc;display:block}figcaption{word-break:break-word}
";

/// The report as one self-contained page: no external styles, scripts or fonts; images are
/// the files beside it.
pub fn html(report: &AccuracyReport) -> String {
    let mut h = String::new();
    let r = report;
    let _ = write!(
        h,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\
         <title>vkrt bench accuracy</title><style>{STYLE}</style></head><body>\n\
         <h1>vkrt bench accuracy</h1>\n<dl class=\"meta\">"
    );
    let rays = format!(
        "{} primary, {} shadow, {} secondary",
        fmt_count(r.rays.primary as u64),
        fmt_count(r.rays.shadow as u64),
        fmt_count(r.rays.secondary as u64)
    );
    let run = format!(
        "{}, {} s wall",
        if r.quick { "quick" } else { "full" },
        fmt_num(r.wall_s)
    );
    let rows = [
        ("device", escape(&r.device)),
        ("driver", escape(&r.driver)),
        ("command", format!("<code>{}</code>", escape(&r.command))),
        ("run", run),
        ("mesh", escape(&r.mesh)),
        ("rays", rays),
        ("hard cases", escape(&r.hard_cases)),
    ];
    for (k, v) in rows {
        let _ = write!(h, "<dt>{k}</dt><dd>{v}</dd>");
    }
    for note in &r.notes {
        let _ = write!(h, "<dt>note</dt><dd>{}</dd>", escape(note));
    }
    h.push_str("</dl>\n<h2>Recommendations</h2>\n<div class=\"scroll\"><table><tr><th>use</th><th>group</th><th>setting</th><th>why</th></tr>\n");
    for rec in &r.recommendations {
        let _ = writeln!(
            h,
            "<tr><td>{}</td><td>{}</td><td><b>{}</b></td><td>{}</td></tr>",
            escape(&rec.use_case),
            escape(&rec.group),
            escape(&rec.setting),
            escape(&rec.why)
        );
    }
    h.push_str("</table></div>\n");
    for g in &r.groups {
        group_section(&mut h, g);
    }
    images_section(&mut h, r);
    h.push_str("</body></html>\n");
    h
}

fn group_section(h: &mut String, g: &KnobGroup) {
    let _ = write!(
        h,
        "<h2 id=\"{}\">{}</h2>\n<p class=\"axes\">time: {} · error: {} · preview tolerates error ≤ {} · \
         uses: {} · ★ = on the Pareto front</p>\n<div class=\"plot\">{}</div>\n",
        escape(&g.id),
        escape(&g.title),
        escape(&g.time_axis),
        escape(&g.error_axis),
        fmt_num(g.preview_error_max),
        escape(&g.uses.join(", ")),
        plot_svg(g)
    );
    let unplotted: Vec<String> = (g.points.iter())
        .filter(|p| !(p.time_ms.is_finite() && p.error.is_finite()))
        .map(|p| escape(&p.setting))
        .collect();
    if !unplotted.is_empty() {
        let _ = writeln!(
            h,
            "<p class=\"axes\">not plotted (time or error not a number): {}</p>",
            unplotted.join(", ")
        );
    }
    // Columns no point of the group has are left out: each group measures a few.
    let cols: Vec<&Column> = COLUMNS
        .iter()
        .filter(|c| g.points.iter().any(|p| (c.cell)(p).is_some()))
        .collect();
    h.push_str("<div class=\"scroll\"><table><tr><th>setting</th><th>time ms</th><th>error</th>");
    for c in &cols {
        let _ = write!(h, "<th>{}</th>", c.name);
    }
    h.push_str("<th>note</th></tr>\n");
    for (i, p) in g.points.iter().enumerate() {
        let on_front = g.front.contains(&i);
        let _ = write!(
            h,
            "<tr{}><td>{}{}</td><td class=\"n\">{}</td><td class=\"n\">{}</td>",
            if on_front { " class=\"front\"" } else { "" },
            if on_front { "★ " } else { "" },
            escape(&p.setting),
            fmt_num(p.time_ms),
            fmt_num(p.error)
        );
        for c in &cols {
            let class = if c.numeric { "n" } else { "imgs" };
            let v = (c.cell)(p).unwrap_or_else(|| "—".into());
            let _ = write!(h, "<td class=\"{class}\">{v}</td>");
        }
        let note = p.note.as_deref().map_or("—".into(), escape);
        let _ = writeln!(h, "<td>{note}</td></tr>");
    }
    h.push_str("</table></div>\n");
}

/// A column of the points table: its header and a cell's HTML, `None` for "not measured".
struct Column {
    name: &'static str,
    numeric: bool,
    cell: fn(&Point) -> Option<String>,
}

const COLUMNS: &[Column] = &[
    Column {
        name: "build ms",
        numeric: true,
        cell: |p| p.costs.build_ms.map(fmt_num),
    },
    Column {
        name: "update ms",
        numeric: true,
        cell: |p| p.costs.update_ms.map(fmt_num),
    },
    Column {
        name: "trace ms<br>primary / shadow / secondary",
        numeric: true,
        cell: |p| {
            p.costs.trace_ms.map(|t| {
                format!(
                    "{} / {} / {}",
                    fmt_num(t.primary),
                    fmt_num(t.shadow),
                    fmt_num(t.secondary)
                )
            })
        },
    },
    Column {
        name: "render ms",
        numeric: true,
        cell: |p| p.costs.render_ms.map(fmt_num),
    },
    Column {
        name: "SAH cost",
        numeric: true,
        cell: |p| p.costs.sah_cost.map(fmt_num),
    },
    Column {
        name: "bytes",
        numeric: true,
        cell: |p| p.costs.bytes.map(fmt_bytes),
    },
    Column {
        name: "hard cases<br>rays: misses / self-hits / wrong / errors",
        numeric: true,
        cell: |p| {
            p.accuracy.hard_cases.map(|c| {
                format!(
                    "{}: {} / {} / {} / {}",
                    fmt_count(c.rays),
                    fmt_count(c.misses),
                    fmt_count(c.self_hits),
                    fmt_count(c.wrong_hits),
                    fmt_count(c.errors)
                )
            })
        },
    },
    Column {
        name: "hit differences",
        numeric: true,
        cell: |p| p.accuracy.hit_differences.map(fmt_count),
    },
    Column {
        name: "SAH ratio",
        numeric: true,
        cell: |p| p.accuracy.sah_ratio.map(fmt_num),
    },
    Column {
        name: "images<br>scene: RMSE / worst",
        numeric: false,
        cell: |p| {
            let lines: Vec<String> = (p.accuracy.images.iter())
                .map(|e| {
                    format!(
                        "{}: {} / {}",
                        escape(&e.scene),
                        fmt_num(e.rmse),
                        fmt_num(e.worst)
                    )
                })
                .collect();
            (!lines.is_empty()).then(|| lines.join("<br>"))
        },
    },
];

/// Bytes in B, KiB or MiB.
fn fmt_bytes(b: u64) -> String {
    match b {
        0..1024 => format!("{b} B"),
        1024..1_048_576 => format!("{} KiB", fmt_num(b as f64 / 1024.0)),
        _ => format!("{} MiB", fmt_num(b as f64 / 1_048_576.0)),
    }
}

fn images_section(h: &mut String, r: &AccuracyReport) {
    if r.image_scenes.is_empty() {
        return;
    }
    h.push_str("<h2>Images</h2>\n");
    for s in &r.image_scenes {
        let _ = write!(
            h,
            "<h3>{}</h3>\n<div class=\"figs\"><figure class=\"ref\"><img src=\"{}\" alt=\"reference\">\
             <figcaption>reference: {}×{}, {} spp, depth {}</figcaption></figure></div>\n",
            escape(&s.name),
            escape(&s.reference_file),
            s.width,
            s.height,
            s.reference_spp,
            s.reference_depth
        );
        for g in &r.groups {
            let figs: Vec<String> = (g.points.iter())
                .flat_map(|p| p.accuracy.images.iter().map(move |e| (p, e)))
                .filter(|(_, e)| e.scene == s.name)
                .map(|(p, e)| {
                    format!(
                        "<figure><img src=\"{}\" alt=\"{}\" loading=\"lazy\"><figcaption>{}<br>RMSE {}, worst {}</figcaption></figure>",
                        escape(&e.file),
                        escape(&p.setting),
                        escape(&p.setting),
                        fmt_num(e.rmse),
                        fmt_num(e.worst)
                    )
                })
                .collect();
            if !figs.is_empty() {
                let _ = writeln!(
                    h,
                    "<p class=\"axes\">{}</p><div class=\"figs\">{}</div>",
                    escape(&g.title),
                    figs.concat()
                );
            }
        }
    }
}
