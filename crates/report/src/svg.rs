//! Small hand-written SVG charts for the report: grouped bars and a scatter
//! plot, with axes, ticks and a legend; no fonts or system libraries needed.

use std::fmt::Write;

const W: f64 = 640.0;
const H: f64 = 320.0;
const LEFT: f64 = 56.0;
const BOTTOM: f64 = 40.0;
const TOP: f64 = 30.0;
const COLOURS: [&str; 6] = [
    "#4e79a7", "#f28e2b", "#59a14f", "#e15759", "#b07aa1", "#76b7b2",
];

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

fn axes(out: &mut String, title: &str, y_label: &str, y_max: f64) {
    let _ = write!(
        out,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{W}" height="{H}" viewBox="0 0 {W} {H}" font-family="sans-serif" font-size="11">"#
    );
    let _ = write!(
        out,
        r#"<rect width="{W}" height="{H}" fill="white"/><text x="{}" y="18" text-anchor="middle" font-size="14">{}</text>"#,
        W / 2.0,
        escape(title)
    );
    let plot_h = H - TOP - BOTTOM;
    for i in 0..=4 {
        let v = y_max * i as f64 / 4.0;
        let y = H - BOTTOM - plot_h * i as f64 / 4.0;
        let _ = write!(
            out,
            r##"<line x1="{LEFT}" x2="{}" y1="{y}" y2="{y}" stroke="#ddd"/><text x="{}" y="{}" text-anchor="end">{}</text>"##,
            W - 10.0,
            LEFT - 4.0,
            y + 4.0,
            format_tick(v)
        );
    }
    let _ = write!(
        out,
        r#"<text transform="translate(14,{}) rotate(-90)" text-anchor="middle">{}</text>"#,
        TOP + plot_h / 2.0,
        escape(y_label)
    );
}

fn format_tick(v: f64) -> String {
    if v >= 100.0 || v == v.round() {
        format!("{v:.0}")
    } else {
        format!("{v:.1}")
    }
}

/// Grouped bars: one group per category, one bar per series (`None` = missing).
pub fn bars(
    title: &str,
    y_label: &str,
    categories: &[String],
    series: &[(String, Vec<Option<f64>>)],
) -> String {
    let y_max = series
        .iter()
        .flat_map(|s| s.1.iter().flatten())
        .copied()
        .fold(0.0f64, f64::max)
        .max(1e-9)
        * 1.1;
    let mut out = String::new();
    axes(&mut out, title, y_label, y_max);
    let plot_w = W - LEFT - 10.0;
    let plot_h = H - TOP - BOTTOM;
    let group = plot_w / categories.len().max(1) as f64;
    let bar = group * 0.8 / series.len().max(1) as f64;
    for (c, name) in categories.iter().enumerate() {
        let gx = LEFT + group * c as f64 + group * 0.1;
        let _ = write!(
            out,
            r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
            gx + group * 0.4,
            H - BOTTOM + 14.0,
            escape(name)
        );
        for (s, (_, values)) in series.iter().enumerate() {
            if let Some(v) = values.get(c).copied().flatten() {
                let h = plot_h * v / y_max;
                let _ = write!(
                    out,
                    r#"<rect x="{:.1}" y="{:.1}" width="{:.1}" height="{:.1}" fill="{}"><title>{:.2}</title></rect>"#,
                    gx + bar * s as f64,
                    H - BOTTOM - h,
                    bar * 0.9,
                    h,
                    COLOURS[s % 6],
                    v
                );
            }
        }
    }
    legend(&mut out, series.iter().map(|s| s.0.as_str()));
    out.push_str("</svg>");
    out
}

/// A scatter plot of labelled points, one colour per series.
pub fn scatter(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[(String, Vec<(f64, f64)>)],
) -> String {
    let pts = series.iter().flat_map(|s| s.1.iter());
    let (x_max, y_max) = pts.fold((0.0f64, 0.0f64), |(a, b), &(x, y)| (a.max(x), b.max(y)));
    let (x_max, y_max) = (x_max.max(1e-9) * 1.1, y_max.max(1e-9) * 1.1);
    let mut out = String::new();
    axes(&mut out, title, y_label, y_max);
    let plot_w = W - LEFT - 10.0;
    let plot_h = H - TOP - BOTTOM;
    for i in 0..=4 {
        let v = x_max * i as f64 / 4.0;
        let _ = write!(
            out,
            r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
            LEFT + plot_w * i as f64 / 4.0,
            H - BOTTOM + 14.0,
            format_tick(v)
        );
    }
    let _ = write!(
        out,
        r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
        LEFT + plot_w / 2.0,
        H - 8.0,
        escape(x_label)
    );
    for (s, (_, points)) in series.iter().enumerate() {
        for &(x, y) in points {
            let _ = write!(
                out,
                r#"<circle cx="{:.1}" cy="{:.1}" r="4" fill="{}" fill-opacity="0.8"/>"#,
                LEFT + plot_w * x / x_max,
                H - BOTTOM - plot_h * y / y_max,
                COLOURS[s % 6]
            );
        }
    }
    legend(&mut out, series.iter().map(|s| s.0.as_str()));
    out.push_str("</svg>");
    out
}

fn legend<'a>(out: &mut String, names: impl Iterator<Item = &'a str>) {
    for (i, n) in names.enumerate() {
        let x = LEFT + 8.0 + 100.0 * i as f64;
        let _ = write!(
            out,
            r#"<rect x="{x}" y="{}" width="10" height="10" fill="{}"/><text x="{}" y="{}">{}</text>"#,
            TOP - 4.0,
            COLOURS[i % 6],
            x + 14.0,
            TOP + 5.0,
            escape(n)
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn charts_are_well_formed_svg() {
        let b = bars(
            "t",
            "dB",
            &["a".into(), "b<".into()],
            &[
                ("ours".into(), vec![Some(3.0), None]),
                ("paper".into(), vec![Some(1.0), Some(2.0)]),
            ],
        );
        assert!(b.starts_with("<svg") && b.ends_with("</svg>") && b.contains("b&lt;"));
        assert_eq!(b.matches("<rect x=").count(), 3 + 2);
        let s = scatter(
            "t",
            "ms",
            "%",
            &[("wta".into(), vec![(1.0, 2.0), (3.0, 4.0)])],
        );
        assert_eq!(s.matches("<circle").count(), 2);
    }
}
