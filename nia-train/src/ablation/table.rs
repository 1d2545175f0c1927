//! The ablation's table: its rows in markdown, and the paper's orderings (NIA Table 3), each
//! marked as holding or not.

use nia_model::variant::Variant;

use super::AblationRow;
use crate::config::TrainConfig;

/// The markdown table and the paper's orderings, each marked as holding or not.
pub fn ablation_markdown(config: &TrainConfig, rows: &[AblationRow]) -> String {
    let t = &config.train;
    let mut md = String::new();
    md.push_str("# Ablation (NIA Table 3) on the held-out subjects\n\n");
    md.push_str(&format!(
        "Each variant trained for {} steps of {} rays x {} samples with {} source views \
         (equal budget), backend `{}`. PSNR over `mask_at_box`, SSIM on its bounding crop.\n\n",
        t.steps,
        t.rays_per_step,
        t.samples,
        t.source_views,
        t.backend.name()
    ));
    md.push_str(
        "| variant | task | views | images | PSNR (dB) | SSIM | PSNR, no skipping | SSIM, no skipping | c0 share (seen) | train (s) | eval (s/image) |\n\
         |---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n",
    );
    let opt = |v: Option<f64>, digits: usize| {
        v.map(|x| format!("{x:.digits$}"))
            .unwrap_or_else(|| "-".into())
    };
    for r in rows {
        md.push_str(&format!(
            "| {} | {} | {} | {} | {:.2} | {:.4} | {} | {} | {} | {:.0} | {:.2} |\n",
            r.label,
            r.task.replace('_', " "),
            r.views,
            r.images,
            r.psnr,
            r.ssim,
            opt(r.psnr_no_skip, 2),
            opt(r.ssim_no_skip, 4),
            opt(r.c0_share_seen, 2),
            r.train_seconds,
            r.seconds_per_image
        ));
    }
    md.push_str("\nThe paper's orderings (PSNR, skipping on):\n\n");
    for line in orderings(rows) {
        md.push_str(&format!("- {line}\n"));
    }
    md
}

/// The paper's orderings e > d > c, e > a, e > b and 1 < 2 < 3 views, each with its verdict.
pub fn orderings(rows: &[AblationRow]) -> Vec<String> {
    let novel_view = |variant: Variant, views: Option<usize>| {
        rows.iter()
            .find(|r| {
                r.variant == variant && r.task == "novel_view" && views.is_none_or(|v| r.views == v)
            })
            .map(|r| r.psnr)
    };
    let full_views = rows
        .iter()
        .filter(|r| r.variant == Variant::Full && r.task == "novel_view")
        .map(|r| r.views)
        .max();
    let mut lines = Vec::new();
    let mut check = |name: String, pairs: Vec<(Option<f64>, Option<f64>)>| {
        let values: Option<Vec<(f64, f64)>> =
            pairs.into_iter().map(|(a, b)| Some((a?, b?))).collect();
        let verdict = match values {
            None => "not measured".to_string(),
            Some(v) => {
                let holds = v.iter().all(|(a, b)| a > b);
                let gaps: Vec<String> =
                    v.iter().map(|(a, b)| format!("{:+.2} dB", a - b)).collect();
                format!(
                    "{} ({})",
                    if holds { "holds" } else { "does not hold" },
                    gaps.join(", ")
                )
            }
        };
        lines.push(format!("{name}: {verdict}"));
    };
    let e = novel_view(Variant::Full, full_views);
    let d = novel_view(Variant::CosineWeighted, None);
    let c = novel_view(Variant::SimpleAverage, None);
    check("e > d > c".into(), vec![(e, d), (d, c)]);
    check("e > a".into(), vec![(e, novel_view(Variant::NoBody, None))]);
    check("e > b".into(), vec![(e, novel_view(Variant::NoIbr, None))]);
    if let Some(n) = full_views {
        let by_views: Vec<Option<f64>> = (1..=n)
            .map(|v| novel_view(Variant::Full, Some(v)))
            .collect();
        let pairs = by_views.windows(2).map(|w| (w[1], w[0])).collect();
        let names: Vec<String> = (1..=n).map(|v| v.to_string()).collect();
        check(format!("{} views", names.join(" < ")), pairs);
    }
    lines
}
