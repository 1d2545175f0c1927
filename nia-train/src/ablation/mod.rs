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

use burn::prelude::*;
use image::RgbImage;
use nia_data::dataset::protocol::{EvalItem, EvalSplit};
use nia_eval::eval::{eval_items, evaluate_images, EvalError, EvalOptions, EvalTask, ImageResult};
use nia_eval::pictures::{rgb8, row, save_png};
use nia_model::renderer::call_size::rays_per_chunk;
use nia_model::store::checkpoint::{self, CheckpointError};
use nia_model::variant::Variant;
use nia_model::NiaModel;
use serde::Serialize;

use crate::config::TrainConfig;
use crate::data::TrainData;
use crate::events::TrainEvent;
use crate::train_loop::{train, RunOptions, TrainError};

mod table;

pub use table::{ablation_markdown, orderings};

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
    let setup = Setup::open(config, on_event)?;
    let mut rows = Vec::new();
    // Tiles of the first held-out image: ground truth, then one per row.
    let mut tiles: Vec<RgbImage> = Vec::new();
    let mut crop: Option<Crop> = None;
    for variant in Variant::ALL {
        let run = VariantRun::train(config, &setup, out, variant, on_event)?;
        let label = format!("({}) {}", run.letter, run.name);
        let mut case = EvalCase {
            label: &label,
            items: &setup.items,
            task: EvalTask::NovelView,
            skip: true,
        };
        let on = run.evaluate(&setup, &case, &mut crop, on_event)?;
        let no_skipping = format!("{label}, no skipping");
        case.label = &no_skipping;
        case.skip = false;
        let off = run.evaluate(&setup, &case, &mut crop, on_event)?;
        if let Some((tile, gt)) = on.picture {
            if tiles.is_empty() {
                tiles.extend(gt);
            }
            tiles.push(tile);
        }
        let views = setup.items[0].input_views.len();
        let row = run.row(
            RowInputs {
                label,
                views,
                task: "novel_view",
                on: &on.results,
                off: Some(&off.results),
            },
            on.seconds_per_image,
        );
        on_event(AblationEvent::Row(&row));
        rows.push(row);
        if variant == Variant::Full {
            let (full_rows, full_tiles) =
                run.full_model_rows(&setup, views, &mut crop, on_event)?;
            rows.extend(full_rows);
            tiles.extend(full_tiles);
        }
    }
    write_report(config, out, rows, &tiles)
}

/// What every variant shares: the data, the device and the evaluation items (opening
/// generates a `[synth]` dataset if it is missing, so training finds it).
struct Setup {
    data: TrainData,
    device: Device,
    /// The novel views of the unseen subjects.
    items: Vec<EvalItem>,
}

impl Setup {
    fn open(
        config: &TrainConfig,
        on_event: &mut dyn FnMut(AblationEvent<'_>),
    ) -> Result<Self, AblationError> {
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
        let items = eval_items(&data.dataset, SPLIT, EvalTask::NovelView, None)
            .map_err(|e| AblationError::Setup(Box::new(e.into())))?;
        if items.is_empty() {
            return Err(AblationError::NothingToEvaluate);
        }
        Ok(Setup {
            data,
            device,
            items,
        })
    }
}

/// The split every row is evaluated on.
const SPLIT: EvalSplit = EvalSplit::UnseenSubjects;

/// One variant, trained: its run config, the model of its newest checkpoint and its training
/// time.
struct VariantRun {
    variant: Variant,
    name: String,
    /// Its letter in the paper's Table 3.
    letter: char,
    config: TrainConfig,
    model: NiaModel,
    train_seconds: f64,
}

/// One evaluation of a variant: the per-image results, the mean seconds per image and the
/// tile of its first image (with the ground truth's).
struct Evaluated {
    results: Vec<ImageResult>,
    seconds_per_image: f64,
    picture: Option<(RgbImage, Option<RgbImage>)>,
}

/// One evaluation of the ablation: its label, the items and task, and whether empty-space
/// skipping is on.
struct EvalCase<'a> {
    label: &'a str,
    items: &'a [EvalItem],
    task: EvalTask,
    skip: bool,
}

/// What one row of the table summarises, besides the variant's own figures.
struct RowInputs<'a> {
    label: String,
    /// Source views at evaluation.
    views: usize,
    task: &'static str,
    /// The per-image results with empty-space skipping on, and off where measured.
    on: &'a [ImageResult],
    off: Option<&'a [ImageResult]>,
}

impl VariantRun {
    /// `variant` of `config` trained into `out/<variant>` (without validation or final
    /// evaluation) and its newest checkpoint loaded.
    fn train(
        config: &TrainConfig,
        setup: &Setup,
        out: &Path,
        variant: Variant,
        on_event: &mut dyn FnMut(AblationEvent<'_>),
    ) -> Result<Self, AblationError> {
        let name = variant.name().to_string();
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
        let model = checkpoint::load_model(&last, run_config.model.init(&setup.device))
            .map_err(checkpoint_err)?;
        Ok(VariantRun {
            variant,
            letter: paper_letter(variant),
            name,
            config: run_config,
            model,
            train_seconds,
        })
    }

    /// The model on `case`; the first image's tile is cut to `crop` (the first scored region
    /// of the ablation).
    fn evaluate(
        &self,
        setup: &Setup,
        case: &EvalCase<'_>,
        crop: &mut Option<Crop>,
        on_event: &mut dyn FnMut(AblationEvent<'_>),
    ) -> Result<Evaluated, AblationError> {
        on_event(AblationEvent::Evaluating { label: case.label });
        let mut adaptive = self.config.render;
        adaptive.skip_empty_space = case.skip;
        let started = Instant::now();
        let mut picture = None;
        let samples = self.config.train.samples;
        let results = evaluate_images(
            &self.model,
            &setup.data.dataset,
            SPLIT,
            case.items,
            EvalOptions {
                task: case.task,
                samples,
                chunk: rays_per_chunk(&setup.device, samples, &adaptive),
                timed: false,
                render: adaptive,
                lpips: None,
                truth: None,
            },
            &setup.device,
            &mut |e| {
                if picture.is_none() {
                    let (w, h) = (e.rendered.width, e.rendered.height);
                    let gt = rgb8(&e.ground_truth.image, w, h);
                    let c = *crop.get_or_insert_with(|| Crop::of(e.mask_at_box, w, h));
                    picture = Some((c.apply(&rgb8(&e.rendered.rgb, w, h)), Some(c.apply(&gt))));
                }
                Ok(())
            },
        )
        .map_err(|source| AblationError::Eval {
            variant: self.name.clone(),
            source: Box::new(source),
        })?;
        let seconds_per_image = started.elapsed().as_secs_f64() / results.len().max(1) as f64;
        Ok(Evaluated {
            results,
            seconds_per_image,
            picture,
        })
    }

    /// The full model (e) with fewer source views than the `views` it was trained with, then
    /// in novel poses (no row where no frame has another to repose from): their rows, and the
    /// tiles of the fewer views.
    fn full_model_rows(
        &self,
        setup: &Setup,
        views: usize,
        crop: &mut Option<Crop>,
        on_event: &mut dyn FnMut(AblationEvent<'_>),
    ) -> Result<(Vec<AblationRow>, Vec<RgbImage>), AblationError> {
        let (mut rows, mut tiles) = (Vec::new(), Vec::new());
        let fewer_views = (1..views).rev().map(|fewer| {
            let label = format!(
                "(e) full, {fewer} view{}",
                if fewer == 1 { "" } else { "s" }
            );
            let subset: Vec<EvalItem> = setup
                .items
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
            setup.items.clone(),
            EvalTask::NovelPose {
                reference_frame: None,
            },
            views,
        );
        for (label, subset, task, used_views) in fewer_views.chain([novel_pose]) {
            let pose = matches!(task, EvalTask::NovelPose { .. });
            let case = EvalCase {
                label: &label,
                items: &subset,
                task,
                skip: true,
            };
            let evaluated = self.evaluate(setup, &case, crop, on_event)?;
            if let Some((tile, _)) = evaluated.picture.filter(|_| !pose) {
                tiles.push(tile);
            }
            if pose && evaluated.results.is_empty() {
                continue;
            }
            let task_name = if pose { "novel_pose" } else { "novel_view" };
            let row = self.row(
                RowInputs {
                    label,
                    views: used_views,
                    task: task_name,
                    on: &evaluated.results,
                    off: None,
                },
                evaluated.seconds_per_image,
            );
            on_event(AblationEvent::Row(&row));
            rows.push(row);
        }
        Ok((rows, tiles))
    }

    /// A row from the per-image results with skipping on (and off, where measured).
    fn row(&self, inputs: RowInputs<'_>, seconds_per_image: f64) -> AblationRow {
        let RowInputs {
            label,
            views,
            task,
            on,
            off,
        } = inputs;
        let mean = |r: &[ImageResult], f: fn(&ImageResult) -> f64| {
            r.iter().map(f).sum::<f64>() / r.len().max(1) as f64
        };
        let seen: Vec<f64> = on
            .iter()
            .filter_map(|x| x.diagnostics.c0_weight_seen)
            .collect();
        AblationRow {
            label,
            variant: self.variant,
            views,
            task,
            images: on.len(),
            psnr: mean(on, |r| r.psnr),
            ssim: mean(on, |r| r.ssim),
            psnr_no_skip: off.map(|r| mean(r, |x| x.psnr)),
            ssim_no_skip: off.map(|r| mean(r, |x| x.ssim)),
            train_seconds: self.train_seconds,
            seconds_per_image,
            c0_share_seen: (!seen.is_empty()).then(|| seen.iter().sum::<f64>() / seen.len() as f64),
        }
    }
}

/// The table (`ablation.md`, `ablation.json`) and the picture (`ablation.png`) of `rows` and
/// `tiles` under `out`.
fn write_report(
    config: &TrainConfig,
    out: &Path,
    rows: Vec<AblationRow>,
    tiles: &[RgbImage],
) -> Result<AblationReport, AblationError> {
    let table = out.join("ablation.md");
    write_file(&table, ablation_markdown(config, &rows).as_bytes())?;
    let json = serde_json::to_string_pretty(&rows).unwrap_or_default();
    write_file(&out.join("ablation.json"), json.as_bytes())?;
    let picture = out.join("ablation.png");
    save_png(&picture, &row(tiles)).map_err(|e| AblationError::Picture(e.to_string()))?;
    Ok(AblationReport {
        rows,
        table,
        picture,
    })
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
