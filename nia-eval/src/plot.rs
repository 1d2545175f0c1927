//! Plots as SVG through plotters (its SVG backend only: no font or bitmap stack): the
//! accuracy-time scatter of `nia-infer sweep` (log-scale x, the Pareto front drawn over the
//! points) and the training curves of `nia-train` (loss and PSNR against steps).

use plotters::coord::Shift;
use plotters::prelude::*;

/// A plot could not be drawn (plotters' message).
#[derive(Debug, thiserror::Error)]
#[error("plot `{title}`: {message}")]
pub struct PlotError {
    pub title: String,
    pub message: String,
}

fn plot_err<E: std::fmt::Debug>(title: &str) -> impl Fn(E) -> PlotError + '_ {
    move |e| PlotError {
        title: title.to_string(),
        message: format!("{e:?}"),
    }
}

/// Points of one colour.
pub struct Series {
    pub name: String,
    pub colour: RGBColor,
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

/// `[lo, hi]` of `values` widened by `pad` of its span (a unit span when empty or flat).
fn padded_range(values: impl Iterator<Item = f64>, pad: f64) -> (f64, f64) {
    let (lo, hi) = values
        .filter(|v| v.is_finite())
        .fold((f64::MAX, f64::MIN), |(a, b), v| (a.min(v), b.max(v)));
    if lo > hi {
        return (0.0, 1.0);
    }
    let span = if hi - lo < 1e-9 { 1.0 } else { hi - lo };
    (lo - pad * span, hi + pad * span)
}

/// The accuracy-time plot: `series` as dots labelled with their labels, `front` ((x, y)
/// sorted by x) as a dashed line with rings on its points; x on a log scale (x > 0 only).
pub fn scatter_svg(
    title: &str,
    x_label: &str,
    y_label: &str,
    series: &[Series],
    front: &[(f64, f64)],
) -> Result<String, PlotError> {
    let err = plot_err(title);
    let valid = |x: f64, y: f64| x > 0.0 && x.is_finite() && y.is_finite();
    let all: Vec<(f64, f64)> = series
        .iter()
        .flat_map(|s| s.points.iter().map(|p| (p.0, p.1)))
        .filter(|&(x, y)| valid(x, y))
        .collect();
    let (lx0, lx1) = padded_range(all.iter().map(|p| p.0.log10()), 0.05);
    let (y0, y1) = padded_range(all.iter().map(|p| p.1), 0.08);
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, (820, 500)).into_drawing_area();
        root.fill(&WHITE).map_err(&err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, ("sans-serif", 18))
            .margin(12)
            .x_label_area_size(42)
            .y_label_area_size(56)
            .build_cartesian_2d((10f64.powf(lx0)..10f64.powf(lx1)).log_scale(), y0..y1)
            .map_err(&err)?;
        chart
            .configure_mesh()
            .x_desc(x_label)
            .y_desc(y_label)
            .x_label_formatter(&|v| {
                if *v >= 1.0 {
                    format!("{v:.0}")
                } else {
                    format!("{v:.2}")
                }
            })
            .y_label_formatter(&|v| format!("{v:.1}"))
            .light_line_style(RGBColor(238, 238, 238))
            .draw()
            .map_err(&err)?;
        let green = RGBColor(44, 160, 44);
        if front.len() > 1 {
            chart
                .draw_series(DashedLineSeries::new(
                    front.iter().copied(),
                    6,
                    4,
                    green.stroke_width(2),
                ))
                .map_err(&err)?;
        }
        chart
            .draw_series(
                front
                    .iter()
                    .map(|&(x, y)| Circle::new((x, y), 7, green.stroke_width(2))),
            )
            .map_err(&err)?
            .label("Pareto front")
            .legend(move |(x, y)| Circle::new((x + 10, y), 6, green.stroke_width(2)));
        for s in series {
            let colour = s.colour;
            chart
                .draw_series(
                    s.points
                        .iter()
                        .filter(|p| valid(p.0, p.1))
                        .map(|(x, y, label)| {
                            EmptyElement::at((*x, *y))
                                + Circle::new((0, 0), 4, colour.filled())
                                + Text::new(
                                    label.clone(),
                                    (6, -12),
                                    ("sans-serif", 10).into_font().color(&RGBColor(90, 90, 90)),
                                )
                        }),
                )
                .map_err(&err)?
                .label(s.name.as_str())
                .legend(move |(x, y)| Circle::new((x + 10, y), 4, colour.filled()));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::LowerRight)
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .draw()
            .map_err(&err)?;
        root.present().map_err(&err)?;
    }
    Ok(svg)
}

/// One line of a [`Panel`].
pub struct Curve {
    pub name: String,
    pub colour: RGBColor,
    /// (x, y), in x order.
    pub points: Vec<(f64, f64)>,
    /// Dots on the points (sparse measurements) instead of a thin line.
    pub dots: bool,
    pub width: u32,
}

/// One chart of [`panels_svg`]: its curves against a shared x.
pub struct Panel {
    pub title: String,
    pub y_label: String,
    /// A log-scale y (positive values only).
    pub log_y: bool,
    pub curves: Vec<Curve>,
}

/// `panels` side by side, each its curves against `x_label`.
pub fn panels_svg(x_label: &str, panels: &[Panel]) -> Result<String, PlotError> {
    let mut svg = String::new();
    {
        let width = 520 * panels.len().max(1) as u32;
        let root = SVGBackend::with_string(&mut svg, (width, 420)).into_drawing_area();
        root.fill(&WHITE).map_err(plot_err("curves"))?;
        let areas = root.split_evenly((1, panels.len().max(1)));
        for (panel, area) in panels.iter().zip(&areas) {
            draw_panel(area, x_label, panel)?;
        }
        root.present().map_err(plot_err("curves"))?;
    }
    Ok(svg)
}

fn draw_panel(
    area: &DrawingArea<SVGBackend<'_>, Shift>,
    x_label: &str,
    panel: &Panel,
) -> Result<(), PlotError> {
    let err = plot_err(&panel.title);
    let ok = |&(x, y): &(f64, f64)| x.is_finite() && y.is_finite() && (!panel.log_y || y > 0.0);
    let points = || {
        panel
            .curves
            .iter()
            .flat_map(|c| c.points.iter().filter(|p| ok(p)))
    };
    let (x0, x1) = padded_range(points().map(|p| p.0), 0.02);
    let y_of = |y: f64| if panel.log_y { y.log10() } else { y };
    let (y0, y1) = padded_range(points().map(|p| y_of(p.1)), 0.05);
    // Log scale through log10 values with 10^v labels: one coordinate type for both kinds.
    let label = |v: &f64| {
        if panel.log_y {
            format!("{:.2e}", 10f64.powf(*v))
        } else {
            format!("{v:.1}")
        }
    };
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 16))
        .margin(10)
        .x_label_area_size(38)
        .y_label_area_size(64)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(&err)?;
    chart
        .configure_mesh()
        .x_desc(x_label)
        .y_desc(&panel.y_label)
        .x_label_formatter(&|v| format!("{v:.0}"))
        .y_label_formatter(&label)
        .light_line_style(RGBColor(238, 238, 238))
        .draw()
        .map_err(&err)?;
    for c in &panel.curves {
        let colour = c.colour;
        let pts: Vec<(f64, f64)> = c
            .points
            .iter()
            .filter(|p| ok(p))
            .map(|&(x, y)| (x, y_of(y)))
            .collect();
        let drawn = if c.dots {
            chart
                .draw_series(pts.iter().map(|&p| Circle::new(p, 4, colour.filled())))
                .map_err(&err)?
        } else {
            chart
                .draw_series(LineSeries::new(pts, colour.stroke_width(c.width)))
                .map_err(&err)?
        };
        drawn.label(c.name.as_str()).legend(move |(x, y)| {
            PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2))
        });
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(180, 180, 180))
        .draw()
        .map_err(&err)?;
    Ok(())
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
    fn svg_has_every_point_label_and_the_front() {
        let s = scatter_svg(
            "t",
            "x",
            "y",
            &[Series {
                name: "series a".into(),
                colour: RGBColor(0, 0, 0),
                points: vec![
                    (10.0, 1.0, "p-label".into()),
                    (100.0, 2.0, "q-label".into()),
                ],
            }],
            &[(10.0, 1.0), (100.0, 2.0)],
        )
        .unwrap();
        assert!(s.starts_with("<svg") && s.trim_end().ends_with("</svg>"));
        for text in ["p-label", "q-label", "series a", "Pareto front"] {
            assert!(s.contains(text), "{text}");
        }
        assert!(s.contains("<polyline") || s.contains("<path"), "{s}");
    }

    #[test]
    fn panels_draw_every_curve_and_survive_empty_or_flat_data() {
        let curve = |name: &str, points: Vec<(f64, f64)>, dots| Curve {
            name: name.into(),
            colour: RGBColor(200, 0, 0),
            points,
            dots,
            width: 1,
        };
        let s = panels_svg(
            "step",
            &[
                Panel {
                    title: "loss".into(),
                    y_label: "loss".into(),
                    log_y: true,
                    curves: vec![curve(
                        "raw",
                        vec![(0.0, 0.1), (1.0, 0.01), (2.0, -1.0)],
                        false,
                    )],
                },
                Panel {
                    title: "psnr".into(),
                    y_label: "dB".into(),
                    log_y: false,
                    curves: vec![
                        curve("flat", vec![(0.0, 20.0), (1.0, 20.0)], true),
                        curve("empty", vec![], false),
                    ],
                },
            ],
        )
        .unwrap();
        for text in ["raw", "flat", "empty", "loss", "psnr"] {
            assert!(s.contains(text), "{text}");
        }
    }
}
