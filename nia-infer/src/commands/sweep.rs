//! `nia-infer sweep`: what accuracy costs in time. Over samples per ray, source views,
//! resolution ratio, rays per pixel (supersampling), colour points, the baked density and
//! empty-space skipping, the protocol's
//! PSNR and SSIM with milliseconds and network point evaluations per image: `sweep.csv`,
//! `sweep.md` and `sweep.svg` (PSNR against time, Pareto front marked).

use std::fmt::Write as _;
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use nia_data::dataset::protocol::{EvalItem, EvalSplit};
use nia_eval::eval::{eval_items, EvalOptions, EvalSummary, EvalTask};
use nia_model::render_options::RenderOptions;
use serde::Serialize;

use crate::model_load::{LoadedModel, ModelArgs};
use crate::output::{progress_bar, write_text};
use nia_eval::plot::{pareto_front, scatter_svg, Series};
use plotters::style::RGBColor;

#[derive(Args, Debug)]
pub struct SweepArgs {
    #[command(flatten)]
    pub model: ModelArgs,
    /// Dataset root (default: the model's training data root).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// Samples per ray to try.
    #[arg(long, value_delimiter = ',', default_value = "16,32,64,128")]
    pub sample_counts: Vec<usize>,
    /// Numbers of source views to try (the first k of the protocol's input views).
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    pub view_counts: Vec<usize>,
    /// Image resize ratios to try (of the dataset's native resolution).
    #[arg(long, value_delimiter = ',', default_value = "0.25,0.5")]
    pub ratios: Vec<f32>,
    /// Rays per pixel side to try (every pixel the mean of N x N rays; 1 is the paper's one
    /// ray through the centre).
    #[arg(long, value_delimiter = ',', default_value = "1,2")]
    pub supersamples: Vec<usize>,
    /// Colour points per ray to try (`[render] colour_points`, `--colour-points`: 0 colours every sample, the
    /// paper's; K colours the K samples with the largest weights; default: the model's own).
    #[arg(long, value_delimiter = ',')]
    pub colour_point_counts: Vec<usize>,
    /// Baked-density node spacings to try, metres (`[render] density_grid_m`,
    /// `--density-grid-m`: 0 runs F_sigma at every sample, the paper's; default: the model's
    /// own). Swept with skipping on only (the bake covers what the occupancy grid keeps); every
    /// image is a scene of its own, so a row's time includes one bake per image.
    #[arg(long, value_delimiter = ',')]
    pub density_grids: Vec<f32>,
    /// Images per setting (the first N of the unseen-subject split).
    #[arg(long, default_value_t = 6)]
    pub limit: usize,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(Debug, Clone, Serialize)]
struct Row {
    samples: usize,
    views: usize,
    ratio: f32,
    supersample: usize,
    skip_empty_space: bool,
    colour_points: usize,
    density_grid_m: f32,
    images: usize,
    psnr: f64,
    ssim: f64,
    ms_per_image: f64,
    point_evaluations_per_image: f64,
    pareto: bool,
}

pub fn run(args: &SweepArgs) -> anyhow::Result<()> {
    let loaded = LoadedModel::open(&args.model)?;
    check_counts(args)?;
    let base_adaptive = loaded.render_options(&args.model)?;
    check_render_axes(args, &base_adaptive)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;
    let mut rows = measure(args, &loaded, &base_adaptive)?;
    let points: Vec<(f64, f64)> = rows.iter().map(|r| (r.ms_per_image, r.psnr)).collect();
    for i in pareto_front(&points) {
        rows[i].pareto = true;
    }
    write_text(&args.out.join("sweep.csv"), &csv(&rows))?;
    write_text(&args.out.join("sweep.md"), &markdown(args, &loaded, &rows))?;
    write_text(&args.out.join("sweep.svg"), &svg(&rows)?)?;
    println!("{}", serde_json::to_string_pretty(&rows)?);
    Ok(())
}

/// The swept counts refused before anything runs: fewer than 2 samples, no view, a ratio
/// outside (0, 1].
fn check_counts(args: &SweepArgs) -> anyhow::Result<()> {
    if args.sample_counts.iter().any(|&s| s < 2) {
        anyhow::bail!("--sample-counts: every count must be at least 2");
    }
    if args.view_counts.contains(&0) {
        anyhow::bail!("--view-counts: every count must be at least 1");
    }
    if let Some(r) = args.ratios.iter().find(|r| !(**r > 0.0 && **r <= 1.0)) {
        anyhow::bail!("--ratios: {r} is not in (0, 1]");
    }
    Ok(())
}

/// The swept supersamplings, baked-density spacings and colour points refused where the
/// `[render]` options refuse them.
fn check_render_axes(args: &SweepArgs, base_adaptive: &RenderOptions) -> anyhow::Result<()> {
    let check = |flag: &str, value: String, options: RenderOptions| match options.check() {
        Ok(()) => Ok(()),
        Err(e) => Err(anyhow::anyhow!("{flag} {value}: expected {}", e.expected)),
    };
    for &supersample in &args.supersamples {
        let options = RenderOptions {
            supersample,
            ..*base_adaptive
        };
        check("--supersamples", supersample.to_string(), options)?;
    }
    for &density_grid_m in &args.density_grids {
        let options = RenderOptions {
            density_grid_m,
            ..*base_adaptive
        };
        check("--density-grids", density_grid_m.to_string(), options)?;
    }
    for &colour_points in &args.colour_point_counts {
        let options = RenderOptions {
            colour_points,
            ..*base_adaptive
        };
        check("--colour-point-counts", colour_points.to_string(), options)?;
    }
    Ok(())
}

/// One row per setting: every ratio, view count, sample count and supersampling, with
/// empty-space skipping off and on, evaluated on the first `--limit` unseen-subject images.
fn measure(
    args: &SweepArgs,
    loaded: &LoadedModel,
    base_adaptive: &RenderOptions,
) -> anyhow::Result<Vec<Row>> {
    let split = EvalSplit::UnseenSubjects;
    let colour_points = if args.colour_point_counts.is_empty() {
        vec![base_adaptive.colour_points]
    } else {
        args.colour_point_counts.clone()
    };
    let grids = if args.density_grids.is_empty() {
        vec![base_adaptive.density_grid_m]
    } else {
        args.density_grids.clone()
    };
    // Skipping off and on without a baked density, on only with one.
    let passes: Vec<(f32, bool)> = grids
        .iter()
        .flat_map(|&g| match g > 0.0 {
            true => vec![(g, true)],
            false => vec![(g, false), (g, true)],
        })
        .collect();
    let total = args.ratios.len()
        * args.view_counts.len()
        * args.sample_counts.len()
        * args.supersamples.len()
        * colour_points.len()
        * passes.len();
    let bar = progress_bar(total as u64, "sweep");
    let mut rows = Vec::new();
    for &ratio in &args.ratios {
        let mut data_config = loaded.data_config(args.data.as_deref(), None);
        data_config.ratio = Some(ratio);
        let data = loaded
            .open_split(&data_config, split)
            .with_context(|| format!("at ratio {ratio}"))?;
        let items = eval_items(&data, split, EvalTask::NovelView, Some(args.limit))?;
        for &views in &args.view_counts {
            let items = first_views(&items, views)?;
            for (&samples, &supersample, &points, &(grid, skip)) in args
                .sample_counts
                .iter()
                .flat_map(|s| args.supersamples.iter().map(move |x| (s, x)))
                .flat_map(|(s, x)| colour_points.iter().map(move |k| (s, x, k)))
                .flat_map(|(s, x, k)| passes.iter().map(move |p| (s, x, k, p)))
            {
                let skipping = if skip { "on" } else { "off" };
                bar.set_message(format!(
                    "ratio {ratio}, {views} views, {samples} samples, \
                     {supersample}x{supersample} rays per pixel, {points} colour points, \
                     baked density {grid} m, skipping {skipping}"
                ));
                let render = RenderOptions {
                    skip_empty_space: skip,
                    supersample,
                    colour_points: points,
                    density_grid_m: grid,
                    ..*base_adaptive
                };
                let results = loaded.evaluate(
                    &data,
                    split,
                    &items,
                    EvalOptions {
                        task: EvalTask::NovelView,
                        samples,
                        chunk: loaded.chunk(&args.model, samples, &render),
                        timed: false,
                        render,
                        lpips: None,
                        truth: None,
                    },
                    &mut |_| Ok(()),
                )?;
                let summary = EvalSummary::of(&results).context("no image evaluated")?;
                let n = results.len() as f64;
                rows.push(Row {
                    samples,
                    views,
                    ratio,
                    supersample,
                    skip_empty_space: skip,
                    colour_points: points,
                    density_grid_m: grid,
                    images: summary.images,
                    psnr: summary.psnr,
                    ssim: summary.ssim,
                    ms_per_image: results.iter().map(|r| r.seconds).sum::<f64>() * 1e3 / n,
                    point_evaluations_per_image: results
                        .iter()
                        .map(|r| r.point_evaluations as f64)
                        .sum::<f64>()
                        / n,
                    pareto: false,
                });
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();
    Ok(rows)
}

/// `items` with their first `views` input views (refused where the protocol gives fewer).
fn first_views(items: &[EvalItem], views: usize) -> anyhow::Result<Vec<EvalItem>> {
    if let Some(item) = items.iter().find(|i| i.input_views.len() < views) {
        anyhow::bail!(
            "--view-counts {views}: the protocol gives {} only {} input views",
            item.subject,
            item.input_views.len()
        );
    }
    Ok(items
        .iter()
        .map(|i| EvalItem {
            input_views: i.input_views[..views].to_vec(),
            ..i.clone()
        })
        .collect())
}

/// `sweep.csv`: one line per row.
fn csv(rows: &[Row]) -> String {
    let mut csv = String::from(
        "samples,views,ratio,supersample,skip_empty_space,images,psnr,ssim,ms_per_image,point_evaluations_per_image,pareto,colour_points,density_grid_m\n",
    );
    for r in rows {
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{},{:.4},{:.5},{:.2},{:.0},{},{},{}",
            r.samples,
            r.views,
            r.ratio,
            r.supersample,
            r.skip_empty_space,
            r.images,
            r.psnr,
            r.ssim,
            r.ms_per_image,
            r.point_evaluations_per_image,
            r.pareto,
            r.colour_points,
            r.density_grid_m
        );
    }
    csv
}

/// `sweep.md`: the rows as a table, under what was swept.
fn markdown(args: &SweepArgs, loaded: &LoadedModel, rows: &[Row]) -> String {
    let mut md = format!(
        "# What accuracy costs in time\n\nModel `{}` (step {}), unseen subjects of `{}`, {} images per setting, backend {}.\n\n| ratio | views | samples | rays / pixel | colour points | baked density | skipping | PSNR (dB) | SSIM | ms / image | network points / image | Pareto |\n|---:|---:|---:|---:|---:|---:|:---:|---:|---:|---:|---:|:---:|\n",
        loaded.path.display(),
        loaded.step,
        args.data.as_ref().unwrap_or(&loaded.run.data.root).display(),
        args.limit,
        loaded.backend.name(),
    );
    for r in rows {
        let _ = writeln!(
            md,
            "| {} | {} | {} | {} | {} | {} | {} | {:.2} | {:.4} | {:.0} | {:.0} | {} |",
            r.ratio,
            r.views,
            r.samples,
            r.supersample * r.supersample,
            if r.colour_points == 0 {
                "every sample".to_string()
            } else {
                r.colour_points.to_string()
            },
            if r.density_grid_m > 0.0 {
                format!("{} cm", r.density_grid_m * 100.0)
            } else {
                "-".to_string()
            },
            if r.skip_empty_space { "on" } else { "off" },
            r.psnr,
            r.ssim,
            r.ms_per_image,
            r.point_evaluations_per_image,
            if r.pareto { "**yes**" } else { "" }
        );
    }
    md
}

/// A row's dot label: `r<ratio> v<views> s<samples> x<supersample>`, ` c<K>` where colour
/// is read at K points per ray, and ` g<metres>` where the density is baked.
fn label(r: &Row) -> String {
    let mut label = format!(
        "r{} v{} s{} x{}",
        r.ratio, r.views, r.samples, r.supersample
    );
    if r.colour_points > 0 {
        let _ = write!(label, " c{}", r.colour_points);
    }
    if r.density_grid_m > 0.0 {
        let _ = write!(label, " g{}", r.density_grid_m);
    }
    label
}

/// `sweep.svg`: PSNR against time per image, skipping off and on, the Pareto front drawn.
fn svg(rows: &[Row]) -> anyhow::Result<String> {
    let series = |skip: bool, name: &str, colour: RGBColor| Series {
        name: name.to_string(),
        colour,
        points: rows
            .iter()
            .filter(|r| r.skip_empty_space == skip)
            .map(|r| (r.ms_per_image, r.psnr, label(r)))
            .collect(),
    };
    let mut front: Vec<(f64, f64)> = rows
        .iter()
        .filter(|r| r.pareto)
        .map(|r| (r.ms_per_image, r.psnr))
        .collect();
    front.sort_by(|a, b| a.0.total_cmp(&b.0));
    Ok(scatter_svg(
        "PSNR against time per image (unseen subjects)",
        "milliseconds per image (log scale)",
        "PSNR (dB)",
        &[
            series(false, "skipping off", RGBColor(214, 39, 40)),
            series(true, "skipping on", RGBColor(31, 119, 180)),
        ],
        &front,
    )?)
}
