//! The paper's ablation (NIA Table 3) on one run config: variants (a)..(e) trained at equal
//! budget (the config's steps, rays and samples), each evaluated on the held-out subjects with
//! empty-space skipping on and off, plus the full model (e) with fewer source views and in
//! novel poses.
//!
//! ```text
//! <out>/<variant>/            a training run per variant (checkpoints/, train_seconds.txt)
//! <out>/ablation.md           the table (PSNR, SSIM, seconds) and the paper's orderings
//! <out>/ablation.json         the same rows, machine-readable
//! <out>/ablation.png          one held-out image under every row: ground truth first
//! ```
//!
//! Fewer views are an evaluation of the model trained with the config's source views (F_B takes
//! any number of tokens): the first one or two of the protocol's input views. A rerun resumes
//! each variant from its newest checkpoint, so an interrupted ablation continues where it was.

use std::path::{Path, PathBuf};
use std::time::Instant;

use image::RgbImage;
use nia_data::dataset::protocol::{EvalItem, EvalSplit};
use nia_eval::eval::{eval_items, evaluate_images, EvalError, EvalOptions, EvalTask, ImageResult};
use nia_eval::pictures::{rgb8, row, save_png};
use nia_model::renderer::call_size::rays_per_chunk;
use nia_model::store::checkpoint::{self, CheckpointError};
use nia_model::variant::Variant;
use serde::Serialize;

use crate::config::TrainConfig;
use crate::data::TrainData;
use crate::events::TrainEvent;
use crate::train_loop::{train, RunOptions, TrainError};

/// Errors of an ablation run, naming the variant or file. The training and evaluation errors
/// are boxed: they are the largest, and every `Result` of the run would carry their size.
#[derive(Debug, thiserror::Error)]
pub enum AblationError {
    /// Opening the data, the device or the held-out items.
    #[error("{0}")]
    Setup(Box<TrainError>),
    #[error("variant `{variant}`: {source}")]
    Train {
        variant: String,
        source: Box<TrainError>,
    },
    #[error("variant `{variant}`: evaluation: {source}")]
    Eval {
        variant: String,
        source: Box<EvalError>,
    },
    #[error("variant `{variant}`: {source}")]
    Checkpoint {
        variant: String,
        source: CheckpointError,
    },
    #[error("variant `{0}`: the run wrote no checkpoint (steps = 0?)")]
    NoCheckpoint(String),
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        source: std::io::Error,
    },
    #[error("{0}")]
    Picture(String),
    #[error("the held-out split has no images to evaluate")]
    NothingToEvaluate,
}

/// One row of the table.
#[derive(Debug, Clone, Serialize)]
pub struct AblationRow {
    /// "(a) no_body", ..., "(e) full, 2 views", "(e) full, novel pose".
    pub label: String,
    pub variant: Variant,
    /// Source views at evaluation.
    pub views: usize,
    pub task: &'static str,
    pub images: usize,
    /// Mean PSNR / SSIM with empty-space skipping on (the config's `[render]`).
    pub psnr: f64,
    pub ssim: f64,
    /// The same with skipping off (`None` for the extra rows, evaluated with skipping only).
    pub psnr_no_skip: Option<f64>,
    pub ssim_no_skip: Option<f64>,
    /// Training wall time of the variant (all its runs), seconds.
    pub train_seconds: f64,
    /// Mean evaluation time per image with skipping on, seconds.
    pub seconds_per_image: f64,
    /// Mean NeRF-colour share of the blend where a source view sees the surface.
    pub c0_share_seen: Option<f64>,
}

/// What the ablation reports while it runs.
#[derive(Debug)]
pub enum AblationEvent<'a> {
    /// A training event of `variant`.
    Train {
        variant: Variant,
        event: &'a TrainEvent,
    },
    /// `done` of `total` images of the `[synth]` dataset written (before the first variant).
    Generating {
        done: usize,
        total: usize,
    },
    /// Evaluation of `label` began.
    Evaluating {
        label: &'a str,
    },
    Row(&'a AblationRow),
}

/// The finished ablation.
#[derive(Debug, Clone)]
pub struct AblationReport {
    pub rows: Vec<AblationRow>,
    pub table: PathBuf,
    pub picture: PathBuf,
}

/// Letter of a variant in the paper's Table 3.
pub fn paper_letter(variant: Variant) -> char {
    match variant {
        Variant::NoBody => 'a',
        Variant::NoIbr => 'b',
        Variant::SimpleAverage => 'c',
        Variant::CosineWeighted => 'd',
        Variant::Full => 'e',
    }
}

const SECONDS_FILE: &str = "train_seconds.txt";
/// Upscale of the picture's tiles (nearest neighbour), so single pixels stay visible.
const PICTURE_SCALE: u32 = 3;

/// Trains and evaluates every variant of `config` under `out`.
pub fn run(
    config: &TrainConfig,
    out: &Path,
    on_event: &mut dyn FnMut(AblationEvent<'_>),
) -> Result<AblationReport, AblationError> {
    std::fs::create_dir_all(out).map_err(|source| AblationError::Io {
        path: out.to_path_buf(),
        source,
    })?;
    let mut rows = Vec::new();
    // Tiles of the first held-out image: ground truth, then one per row.
    let mut tiles: Vec<RgbImage> = Vec::new();
    let mut crop: Option<Crop> = None;
    // The data, the device and the evaluation items are the same for every variant (opening
    // generates a `[synth]` dataset if it is missing, so training finds it).
    let data = TrainData::open(config, &mut |done, total| {
        on_event(AblationEvent::Generating { done, total })
    })
    .map_err(|e| AblationError::Setup(Box::new(e.into())))?;
    let device = config
        .train
        .backend
        .device()
        .map_err(|e| AblationError::Setup(Box::new(e.into())))?
        .autodiff();
    let split = EvalSplit::UnseenSubjects;
    let items = eval_items(&data.dataset, split, EvalTask::NovelView, None)
        .map_err(|e| AblationError::Setup(Box::new(e.into())))?;
    if items.is_empty() {
        return Err(AblationError::NothingToEvaluate);
    }
    for variant in Variant::ALL {
        let name = variant.name().to_string();
        let letter = paper_letter(variant);
        let dir = out.join(&name);
        let mut run_config = config.clone();
        run_config.model.variant = variant;
        run_config.train.evaluate_at_end = false;
        run_config.train.validate_every = 0;
        let train_seconds = train_variant(&run_config, &dir, variant, on_event)?;

        let checkpoint_err = |source| AblationError::Checkpoint {
            variant: name.clone(),
            source,
        };
        let (_, last) = checkpoint::latest(&dir)
            .map_err(checkpoint_err)?
            .ok_or_else(|| AblationError::NoCheckpoint(name.clone()))?;
        let model = checkpoint::load_model(&last, run_config.model.init(&device))
            .map_err(checkpoint_err)?;
        let mut evaluate = |on_event: &mut dyn FnMut(AblationEvent<'_>),
                            label: &str,
                            items: &[EvalItem],
                            task: EvalTask,
                            skip: bool,
                            picture: &mut Option<(RgbImage, Option<RgbImage>)>|
         -> Result<(Vec<ImageResult>, f64), AblationError> {
            on_event(AblationEvent::Evaluating { label });
            let mut adaptive = run_config.render;
            adaptive.skip_empty_space = skip;
            let started = Instant::now();
            let mut first = true;
            let results = evaluate_images(
                &model,
                &data.dataset,
                split,
                items,
                EvalOptions {
                    task,
                    samples: run_config.train.samples,
                    chunk: rays_per_chunk(&device, run_config.train.samples, &adaptive),
                    timed: false,
                    render: adaptive,
                    lpips: None,
                },
                &device,
                &mut |e| {
                    if std::mem::take(&mut first) {
                        let (w, h) = (e.rendered.width, e.rendered.height);
                        let gt = rgb8(&e.ground_truth.image, w, h);
                        let c = *crop.get_or_insert_with(|| Crop::of(e.mask_at_box, w, h));
                        *picture =
                            Some((c.apply(&rgb8(&e.rendered.rgb, w, h)), Some(c.apply(&gt))));
                    }
                    Ok(())
                },
            )
            .map_err(|source| AblationError::Eval {
                variant: name.clone(),
                source: Box::new(source),
            })?;
            let seconds = started.elapsed().as_secs_f64() / results.len().max(1) as f64;
            Ok((results, seconds))
        };
        let mut picture = None;
        let (on, seconds) = evaluate(
            on_event,
            &format!("({letter}) {name}"),
            &items,
            EvalTask::NovelView,
            true,
            &mut picture,
        )?;
        let (off, _) = evaluate(
            on_event,
            &format!("({letter}) {name}, no skipping"),
            &items,
            EvalTask::NovelView,
            false,
            &mut None,
        )?;
        if let Some((tile, gt)) = picture {
            if tiles.is_empty() {
                tiles.extend(gt);
            }
            tiles.push(tile);
        }
        let views = items[0].input_views.len();
        let row = summarise(
            format!("({letter}) {name}"),
            variant,
            views,
            "novel_view",
            &on,
            Some(&off),
            train_seconds,
            seconds,
        );
        on_event(AblationEvent::Row(&row));
        rows.push(row);
        if variant != Variant::Full {
            continue;
        }
        // (e) with fewer source views, then in novel poses (no row where no frame has another
        // to repose from).
        let fewer_views = (1..views).rev().map(|fewer| {
            let label = format!(
                "(e) full, {fewer} view{}",
                if fewer == 1 { "" } else { "s" }
            );
            let subset: Vec<EvalItem> = items
                .iter()
                .map(|item| EvalItem {
                    input_views: item.input_views[..fewer].to_vec(),
                    ..item.clone()
                })
                .collect();
            (label, subset, EvalTask::NovelView, fewer)
        });
        let novel_pose = (
            "(e) full, novel pose".to_string(),
            items.clone(),
            EvalTask::NovelPose {
                reference_frame: None,
            },
            views,
        );
        for (label, subset, task, used_views) in fewer_views.chain([novel_pose]) {
            let pose = matches!(task, EvalTask::NovelPose { .. });
            let mut picture = None;
            let (r, seconds) = evaluate(on_event, &label, &subset, task, true, &mut picture)?;
            if let Some((tile, _)) = picture.filter(|_| !pose) {
                tiles.push(tile);
            }
            if pose && r.is_empty() {
                continue;
            }
            let task_name = if pose { "novel_pose" } else { "novel_view" };
            let row = summarise(
                label,
                variant,
                used_views,
                task_name,
                &r,
                None,
                train_seconds,
                seconds,
            );
            on_event(AblationEvent::Row(&row));
            rows.push(row);
        }
    }
    let table = out.join("ablation.md");
    write_file(&table, ablation_markdown(config, &rows).as_bytes())?;
    let json = serde_json::to_string_pretty(&rows).unwrap_or_default();
    write_file(&out.join("ablation.json"), json.as_bytes())?;
    let picture = out.join("ablation.png");
    save_png(&picture, &row(&tiles)).map_err(|e| AblationError::Picture(e.to_string()))?;
    Ok(AblationReport {
        rows,
        table,
        picture,
    })
}

/// A row from the per-image results with skipping on (and off, where measured).
#[allow(clippy::too_many_arguments)]
fn summarise(
    label: String,
    variant: Variant,
    views: usize,
    task: &'static str,
    on: &[ImageResult],
    off: Option<&[ImageResult]>,
    train_seconds: f64,
    seconds_per_image: f64,
) -> AblationRow {
    let mean = |r: &[ImageResult], f: fn(&ImageResult) -> f64| {
        r.iter().map(f).sum::<f64>() / r.len().max(1) as f64
    };
    let seen: Vec<f64> = on
        .iter()
        .filter_map(|x| x.diagnostics.c0_weight_seen)
        .collect();
    AblationRow {
        label,
        variant,
        views,
        task,
        images: on.len(),
        psnr: mean(on, |r| r.psnr),
        ssim: mean(on, |r| r.ssim),
        psnr_no_skip: off.map(|r| mean(r, |x| x.psnr)),
        ssim_no_skip: off.map(|r| mean(r, |x| x.ssim)),
        train_seconds,
        seconds_per_image,
        c0_share_seen: (!seen.is_empty()).then(|| seen.iter().sum::<f64>() / seen.len() as f64),
    }
}

/// Trains one variant into `dir` (resuming from its newest checkpoint), returning its total
/// training seconds over all runs (kept in `dir/train_seconds.txt`).
fn train_variant(
    config: &TrainConfig,
    dir: &Path,
    variant: Variant,
    on_event: &mut dyn FnMut(AblationEvent<'_>),
) -> Result<f64, AblationError> {
    let seconds_path = dir.join(SECONDS_FILE);
    let before: f64 = std::fs::read_to_string(&seconds_path)
        .ok()
        .and_then(|s| s.trim().parse().ok())
        .unwrap_or(0.0);
    let mut this_run = 0.0;
    train(
        config,
        &RunOptions {
            out: dir.to_path_buf(),
            resume: true,
        },
        &mut |event| {
            if let TrainEvent::Finished { seconds, .. } = event {
                this_run = seconds;
            }
            on_event(AblationEvent::Train {
                variant,
                event: &event,
            });
        },
    )
    .map_err(|source| AblationError::Train {
        variant: variant.name().to_string(),
        source: Box::new(source),
    })?;
    let total = before + this_run;
    write_file(&seconds_path, format!("{total:.1}\n").as_bytes())?;
    Ok(total)
}

fn write_file(path: &Path, bytes: &[u8]) -> Result<(), AblationError> {
    std::fs::write(path, bytes).map_err(|source| AblationError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// The rectangle of the scored region of the first image (all tiles use it).
#[derive(Debug, Clone, Copy)]
struct Crop {
    x: u32,
    y: u32,
    w: u32,
    h: u32,
}

impl Crop {
    /// Bounding rectangle of `mask` (the whole image when the mask is empty).
    fn of(mask: &[bool], width: usize, height: usize) -> Self {
        let (mut x0, mut y0, mut x1, mut y1) = (width, height, 0, 0);
        for (i, _) in mask.iter().enumerate().filter(|(_, &m)| m) {
            let (x, y) = (i % width, i / width);
            x0 = x0.min(x);
            y0 = y0.min(y);
            x1 = x1.max(x + 1);
            y1 = y1.max(y + 1);
        }
        if x1 <= x0 || y1 <= y0 {
            return Crop {
                x: 0,
                y: 0,
                w: width as u32,
                h: height as u32,
            };
        }
        Crop {
            x: x0 as u32,
            y: y0 as u32,
            w: (x1 - x0) as u32,
            h: (y1 - y0) as u32,
        }
    }

    fn apply(&self, img: &RgbImage) -> RgbImage {
        let part = image::imageops::crop_imm(img, self.x, self.y, self.w, self.h).to_image();
        image::imageops::resize(
            &part,
            self.w * PICTURE_SCALE,
            self.h * PICTURE_SCALE,
            image::imageops::FilterType::Nearest,
        )
    }
}

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
