//! SVG box plots of error distributions, one box per method, like the
//! paper's Fig. 5: the box spans the quartiles, the line is the median, the
//! diamond the mean, the whiskers reach the farthest value within 1.5
//! inter-quartile ranges, and dots are the values beyond. The value axis is
//! logarithmic, so that sub-centimetre medians and ten-metre failures both
//! show. Plain SVG text: no font library needed.

use std::fmt::Write;

/// One panel: a title, a unit, and per method its values.
pub struct Panel<'a> {
    /// Title, e.g. "translation error".
    pub title: &'a str,
    /// Unit of the values, e.g. "m".
    pub unit: &'a str,
    /// (method name, values).
    pub series: Vec<(&'a str, Vec<f64>)>,
}

struct Stats {
    q1: f64,
    median: f64,
    q3: f64,
    mean: f64,
    low: f64,
    high: f64,
}

fn stats(sorted: &[f64]) -> Stats {
    let at = |q: f64| crate::evaluation::stats::quantile_sorted(sorted, q).unwrap_or(f64::NAN);
    let (q1, median, q3) = (at(0.25), at(0.5), at(0.75));
    let iqr = q3 - q1;
    let low = sorted.iter().copied().find(|v| *v >= q1 - 1.5 * iqr).unwrap_or(q1);
    let high = sorted.iter().rev().copied().find(|v| *v <= q3 + 1.5 * iqr).unwrap_or(q3);
    let mean = crate::evaluation::stats::mean(sorted).unwrap_or(f64::NAN);
    Stats { q1, median, q3, mean, low, high }
}

/// Renders panels side by side as an SVG document.
pub fn render(panels: &[Panel<'_>], caption: &str) -> String {
    let (pw, ph) = (420.0, 360.0);
    let width = pw * panels.len() as f64;
    let height = ph + 30.0;
    let mut svg = String::new();
    let _ = writeln!(
        svg,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(svg, r#"<rect width="100%" height="100%" fill="white"/>"#);
    let _ = writeln!(
        svg,
        r#"<text x="{}" y="20" text-anchor="middle" font-size="14">{}</text>"#,
        width / 2.0,
        escape(caption)
    );
    for (pi, panel) in panels.iter().enumerate() {
        render_panel(&mut svg, panel, pi as f64 * pw, (pw, ph));
    }
    svg.push_str("</svg>\n");
    svg
}

/// A panel's box plots: a log axis over the decades its values span, one
/// box per series.
fn render_panel(svg: &mut String, panel: &Panel<'_>, x0: f64, (pw, ph): (f64, f64)) {
    let (left, top, bottom) = (70.0, 50.0, 50.0);
    let area = Area { x: x0 + left, w: pw - left - 20.0, y: top, h: ph - top - bottom + 30.0 };
    // Decades spanned by the positive finite values (zeros sit on the
    // axis floor), at least one and at most eight.
    let positive = panel.series.iter().flat_map(|(_, v)| v.iter().copied()).filter(|v| v.is_finite() && *v > 0.0);
    let (lo, hi) = positive.fold((f64::INFINITY, 0.0f64), |(l, h), v| (l.min(v), h.max(v)));
    let (lo, hi) = if lo.is_finite() { (lo.max(1e-6), hi.max(lo)) } else { (1e-3, 1.0) };
    let d1 = hi.log10().ceil().max(lo.log10().floor() + 1.0);
    let d0 = lo.log10().floor().max(d1 - 8.0);
    let axis = Axis { area, d0, d1 };
    let (plot_x, plot_y, plot_w, plot_h) = (area.x, area.y, area.w, area.h);
    let _ = writeln!(
        svg,
        r#"<text x="{}" y="{}" text-anchor="middle" font-size="13">{} ({})</text>"#,
        plot_x + plot_w / 2.0,
        top - 12.0,
        escape(panel.title),
        escape(panel.unit)
    );
    let _ = writeln!(
        svg,
        r##"<rect x="{plot_x}" y="{plot_y}" width="{plot_w}" height="{plot_h}" fill="none" stroke="#444"/>"##
    );
    let mut d = d0;
    while d <= d1 + 1e-9 {
        let yy = axis.y(10f64.powf(d));
        let _ = writeln!(svg, r##"<line x1="{plot_x}" x2="{}" y1="{yy}" y2="{yy}" stroke="#ddd"/>"##, plot_x + plot_w);
        let _ = writeln!(
            svg,
            r#"<text x="{}" y="{}" text-anchor="end">{}</text>"#,
            plot_x - 6.0,
            yy + 4.0,
            format_tick(10f64.powf(d))
        );
        d += 1.0;
    }
    let colours = ["#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd"];
    let n = panel.series.len().max(1) as f64;
    for (si, (name, values)) in panel.series.iter().enumerate() {
        let cx = plot_x + plot_w * (si as f64 + 0.5) / n;
        let bw = (plot_w / n * 0.5).min(60.0);
        render_box(svg, &axis, name, values, (cx, bw), colours[si % colours.len()]);
    }
}

/// A plot's area (pixels).
#[derive(Clone, Copy)]
struct Area {
    x: f64,
    w: f64,
    y: f64,
    h: f64,
}

/// A log axis from `10^d0` to `10^d1` over an area.
struct Axis {
    area: Area,
    d0: f64,
    d1: f64,
}

impl Axis {
    fn y(&self, v: f64) -> f64 {
        let a = &self.area;
        a.y + a.h - (v.max(10f64.powf(self.d0)).log10() - self.d0) / (self.d1 - self.d0) * a.h
    }
}

/// One series' box (quartiles, whiskers, median, mean, outliers) at `cx`,
/// `bw` wide.
fn render_box(svg: &mut String, axis: &Axis, name: &str, values: &[f64], (cx, bw): (f64, f64), c: &str) {
    let mut sorted: Vec<f64> = values.iter().copied().filter(|v| v.is_finite()).collect();
    sorted.sort_by(|a, b| a.total_cmp(b));
    if sorted.is_empty() {
        return;
    }
    let st = stats(&sorted);
    let y = |v: f64| axis.y(v);
    let _ = writeln!(svg, r#"<line x1="{cx}" x2="{cx}" y1="{}" y2="{}" stroke="{c}"/>"#, y(st.low), y(st.q1));
    let _ = writeln!(svg, r#"<line x1="{cx}" x2="{cx}" y1="{}" y2="{}" stroke="{c}"/>"#, y(st.q3), y(st.high));
    for v in [st.low, st.high] {
        let _ = writeln!(
            svg,
            r#"<line x1="{}" x2="{}" y1="{}" y2="{}" stroke="{c}"/>"#,
            cx - bw / 4.0,
            cx + bw / 4.0,
            y(v),
            y(v)
        );
    }
    let (top_y, bot_y) = (y(st.q3), y(st.q1));
    let _ = writeln!(
        svg,
        r#"<rect x="{}" y="{top_y}" width="{bw}" height="{}" fill="{c}" fill-opacity="0.25" stroke="{c}"/>"#,
        cx - bw / 2.0,
        (bot_y - top_y).max(1.0)
    );
    let _ = writeln!(
        svg,
        r#"<line x1="{}" x2="{}" y1="{}" y2="{}" stroke="{c}" stroke-width="2"/>"#,
        cx - bw / 2.0,
        cx + bw / 2.0,
        y(st.median),
        y(st.median)
    );
    let ym = y(st.mean);
    let _ = writeln!(
        svg,
        r#"<path d="M{cx} {} L{} {ym} L{cx} {} L{} {ym} Z" fill="{c}"/>"#,
        ym - 4.0,
        cx + 4.0,
        ym + 4.0,
        cx - 4.0
    );
    for v in sorted.iter().filter(|v| **v < st.low || **v > st.high) {
        let _ = writeln!(svg, r#"<circle cx="{cx}" cy="{}" r="2" fill="none" stroke="{c}"/>"#, y(*v));
    }
    let _ = writeln!(
        svg,
        r#"<text x="{cx}" y="{}" text-anchor="middle">{}</text>"#,
        axis.area.y + axis.area.h + 18.0,
        escape(name)
    );
}

fn format_tick(v: f64) -> String {
    if v >= 1.0 {
        format!("{v:.0}")
    } else {
        let digits = (-v.log10()).ceil() as usize;
        format!("{v:.digits$}")
    }
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;").replace('<', "&lt;").replace('>', "&gt;")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn renders_boxes_and_labels() {
        let p = Panel {
            title: "translation error",
            unit: "m",
            series: vec![("cosem", vec![0.01, 0.02, 0.03, 5.0]), ("geometric", vec![0.02, 0.5])],
        };
        let svg = render(&[p], "test");
        assert!(svg.starts_with("<svg") && svg.trim_end().ends_with("</svg>"));
        assert_eq!(svg.matches("<rect").count(), 1 + 1 + 2, "background, frame, two boxes");
        assert!(svg.contains(">cosem</text>") && svg.contains(">geometric</text>"));
        assert!(svg.contains("<circle"), "5.0 is an outlier");
    }

    #[test]
    fn degenerate_values_give_a_finite_axis() {
        for values in [vec![], vec![0.0, 0.0], vec![f64::NAN, f64::INFINITY], vec![1e-30, 1e30]] {
            let p = Panel { title: "t", unit: "m", series: vec![("a", values)] };
            let svg = render(&[p], "x");
            assert!(svg.len() < 20_000 && svg.trim_end().ends_with("</svg>"));
        }
    }

    #[test]
    fn quartiles() {
        let s = stats(&[1.0, 2.0, 3.0, 4.0, 5.0]);
        assert_eq!((s.q1, s.median, s.q3, s.mean), (2.0, 3.0, 4.0, 3.0));
    }
}
