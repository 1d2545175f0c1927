//! A scatter plot as SVG (log-scale x), with a front drawn as a line over the points: enough
//! for the accuracy-time plot, with no plotting dependency.

use std::fmt::Write as _;

/// Points of one colour.
pub struct Series {
    pub name: String,
    pub colour: String,
    /// (x, y, label)
    pub points: Vec<(f64, f64, String)>,
}

/// Indices of the points no other point beats: none is both at most as slow (x) and strictly
/// more accurate (y), or strictly faster and at least as accurate. Here x is time (lower is
/// better) and y is PSNR (higher is better).
pub fn pareto_front(points: &[(f64, f64)]) -> Vec<usize> {
    (0..points.len())
        .filter(|&i| {
            let (xi, yi) = points[i];
            !points
                .iter()
                .any(|&(x, y)| (x <= xi && y > yi) || (x < xi && y >= yi))
        })
        .collect()
}

fn escape(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

/// The plot: `series` as dots (hover titles are their labels), `front` ((x, y) sorted by x)
/// as a dashed line with rings on its points.
pub fn scatter_svg(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    front: &[(f64, f64)],
) -> String {
    let (w, h) = (760.0, 480.0);
    let (left, right, top, bottom) = (70.0, 170.0, 40.0, 60.0);
    let all: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| (p.0, p.1)))
        .filter(|p| p.0 > 0.0 && p.0.is_finite() && p.1.is_finite())
        .collect();
    let (mut x0, mut x1) = all.iter().fold((f64::MAX, f64::MIN), |(a, b), p| {
        (a.min(p.0.log10()), b.max(p.0.log10()))
    });
    let (mut y0, mut y1) = all
        .iter()
        .fold((f64::MAX, f64::MIN), |(a, b), p| (a.min(p.1), b.max(p.1)));
    if all.is_empty() {
        (x0, x1, y0, y1) = (0.0, 1.0, 0.0, 1.0);
    }
    if x1 - x0 < 1e-9 {
        x1 = x0 + 1.0;
    }
    if y1 - y0 < 1e-9 {
        y1 = y0 + 1.0;
    }
    let (px, py) = (0.05 * (x1 - x0), 0.08 * (y1 - y0));
    let (x0, x1, y0, y1) = (x0 - px, x1 + px, y0 - py, y1 + py);
    let sx = |x: f64| left + (x.log10() - x0) / (x1 - x0) * (w - left - right);
    let sy = |y: f64| h - bottom - (y - y0) / (y1 - y0) * (h - top - bottom);
    let mut s = String::new();
    let _ = writeln!(
        s,
        r#"<svg xmlns="http://www.w3.org/2000/svg" width="{w}" height="{h}" viewBox="0 0 {w} {h}" font-family="sans-serif" font-size="12">"#
    );
    let _ = writeln!(s, r#"<rect width="{w}" height="{h}" fill="white"/>"#);
    let _ = writeln!(
        s,
        r#"<text x="{}" y="22" text-anchor="middle" font-size="15">{}</text>"#,
        (w - right + left) / 2.0,
        escape(title)
    );
    // Axes and ticks: powers of 10 and 2x, 5x between them on x; 6 steps on y.
    let _ = writeln!(
        s,
        r##"<path d="M{left} {top} V{} H{}" stroke="#333" fill="none"/>"##,
        h - bottom,
        w - right
    );
    for e in (x0.floor() as i32)..=(x1.ceil() as i32) {
        for m in [1.0, 2.0, 5.0] {
            let v = m * 10f64.powi(e);
            let lv = v.log10();
            if lv < x0 || lv > x1 {
                continue;
            }
            let x = sx(v);
            let _ = writeln!(
                s,
                r##"<line x1="{x:.1}" y1="{}" x2="{x:.1}" y2="{}" stroke="#ddd"/><text x="{x:.1}" y="{}" text-anchor="middle">{}</text>"##,
                top,
                h - bottom,
                h - bottom + 16.0,
                if v >= 1.0 {
                    format!("{v:.0}")
                } else {
                    format!("{v}")
                }
            );
        }
    }
    for i in 0..=6 {
        let v = y0 + (y1 - y0) * i as f64 / 6.0;
        let y = sy(v);
        let _ = writeln!(
            s,
            r##"<line x1="{left}" y1="{y:.1}" x2="{}" y2="{y:.1}" stroke="#eee"/><text x="{}" y="{:.1}" text-anchor="end">{v:.2}</text>"##,
            w - right,
            left - 6.0,
            y + 4.0
        );
    }
    let _ = writeln!(
        s,
        r#"<text x="{}" y="{}" text-anchor="middle">{}</text>"#,
        (w - right + left) / 2.0,
        h - 18.0,
        escape(x_label)
    );
    let _ = writeln!(
        s,
        r#"<text transform="translate(18 {}) rotate(-90)" text-anchor="middle">{}</text>"#,
        (h - bottom + top) / 2.0,
        escape(y_label)
    );
    if front.len() > 1 {
        let d: Vec<String> = front
            .iter()
            .map(|&(x, y)| format!("{:.1},{:.1}", sx(x), sy(y)))
            .collect();
        let _ = writeln!(
            s,
            r##"<polyline points="{}" fill="none" stroke="#2ca02c" stroke-width="2" stroke-dasharray="6 4"/>"##,
            d.join(" ")
        );
    }
    for &(x, y) in front {
        let _ = writeln!(
            s,
            r##"<circle cx="{:.1}" cy="{:.1}" r="7" fill="none" stroke="#2ca02c" stroke-width="2"/>"##,
            sx(x),
            sy(y)
        );
    }
    for (k, ser) in series.iter().enumerate() {
        for (x, y, label) in &ser.points {
            if !(*x > 0.0 && x.is_finite() && y.is_finite()) {
                continue;
            }
            let _ = writeln!(
                s,
                r#"<circle cx="{:.1}" cy="{:.1}" r="3.5" fill="{}"><title>{}: {:.2} dB, {:.0} ms</title></circle>"#,
                sx(*x),
                sy(*y),
                ser.colour,
                escape(label),
                y,
                x
            );
        }
        let ly = top + 20.0 + 20.0 * k as f64;
        let _ = writeln!(
            s,
            r#"<circle cx="{}" cy="{ly}" r="4" fill="{}"/><text x="{}" y="{}">{}</text>"#,
            w - right + 16.0,
            ser.colour,
            w - right + 26.0,
            ly + 4.0,
            escape(&ser.name)
        );
    }
    let ly = top + 20.0 + 20.0 * series.len() as f64;
    let _ = writeln!(
        s,
        r##"<circle cx="{}" cy="{ly}" r="6" fill="none" stroke="#2ca02c" stroke-width="2"/><text x="{}" y="{}">Pareto front</text>"##,
        w - right + 16.0,
        w - right + 26.0,
        ly + 4.0
    );
    s.push_str("</svg>\n");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pareto_front_keeps_the_undominated() {
        // (time, psnr)
        let p = [
            (10.0, 20.0),
            (20.0, 22.0),
            (15.0, 19.0),
            (30.0, 21.0),
            (5.0, 18.0),
        ];
        let mut f = pareto_front(&p);
        f.sort();
        assert_eq!(f, vec![0, 1, 4]);
    }

    #[test]
    fn svg_has_every_point_and_the_front() {
        let s = scatter_svg(
            "t",
            "x",
            "y",
            &[Series {
                name: "a".into(),
                colour: "#000".into(),
                points: vec![(10.0, 1.0, "p".into()), (100.0, 2.0, "q".into())],
            }],
            &[(10.0, 1.0), (100.0, 2.0)],
        );
        assert!(s.starts_with("<svg") && s.ends_with("</svg>\n"));
        assert_eq!(s.matches("<title>").count(), 2);
        assert!(s.contains("<polyline"));
    }
}
