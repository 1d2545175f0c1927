//! `nia-infer eval`: the protocol's PSNR and SSIM (NHP/NIA: PSNR over `mask_at_box`, SSIM on
//! its bounding-rectangle crop) per image, per subject and overall, in `metrics.json`,
//! `metrics.csv` and a `report.md` table; comparison grids (sources | prediction | ground
//! truth | error map) and blend-weight maps (channel 0 = NeRF, 1..N = source views) as PNGs.

use nia_eval::diagnostics::{diagnostics_table, BlendDiagnostics};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use clap::{Args, ValueEnum};
use nia_data::dataset::protocol::{EvalSplit, SubjectSplit};
use nia_data::dataset::{DataConfig, DatasetConfig, ProtocolName};
use nia_data::fitting::SmplAlignment;
use nia_eval::eval::{eval_items, EvalError, EvalOptions, EvalSummary, EvalTask, ImageResult};
use nia_eval::perceptual::LpipsFiles;
use nia_eval::pictures::{save_evaluated, ERROR_MAP_MAX};
use nia_eval::truth::TruthData;
use nia_model::render_options::RenderOptions;
use serde::Serialize;

use crate::model_load::{parse_switch, LoadedModel, LpipsArgs, ModelArgs};
use crate::output::{progress_bar, write_json, write_text};
use crate::session::StageTimesArgs;

#[derive(Clone, Copy, Debug, ValueEnum)]
#[value(rename_all = "snake_case")]
pub enum TaskArg {
    /// Sources and target of the same frame.
    NovelView,
    /// Sources of a reference frame, the body reposed to each evaluated frame.
    NovelPose,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
#[value(rename_all = "snake_case")]
pub enum SplitArg {
    /// The paper's test split: subjects never seen in training.
    Test,
    UnseenSubjects,
    SeenSubjectsUnseenPoses,
    SeenSubjectsSeenPoses,
}

impl SplitArg {
    fn split(self) -> EvalSplit {
        match self {
            SplitArg::Test | SplitArg::UnseenSubjects => EvalSplit::UnseenSubjects,
            SplitArg::SeenSubjectsUnseenPoses => EvalSplit::SeenSubjectsUnseenPoses,
            SplitArg::SeenSubjectsSeenPoses => EvalSplit::SeenSubjectsSeenPoses,
        }
    }
}

#[derive(Args, Debug)]
pub struct EvalArgs {
    #[command(flatten)]
    pub model: ModelArgs,
    /// Dataset root holding the subject folders (default: the model's training data root).
    #[arg(long)]
    pub data: Option<PathBuf>,
    /// SMPL model (default: the model's training setting, else the dataset's body_model.npz).
    #[arg(long)]
    pub smpl: Option<PathBuf>,
    #[arg(long, value_enum, default_value = "test")]
    pub split: SplitArg,
    /// Evaluate these subject folders of --data as held-out people (comma-separated), instead
    /// of the split the data or the model's run config names: for a root without a split of
    /// its own, e.g. one `nia-train prepare` wrote.
    #[arg(long, value_delimiter = ',')]
    pub subjects: Vec<String>,
    /// With --subjects: the input cameras (comma-separated indices; default: 3 spread
    /// evenly); every other camera is a target.
    #[arg(long, value_delimiter = ',', requires = "subjects")]
    pub input_views: Vec<usize>,
    #[arg(long, value_enum, default_value = "novel_view")]
    pub task: TaskArg,
    /// Novel pose: the frame whose images are the sources (default: the first frame of each
    /// subject's range in the split).
    #[arg(long)]
    pub ref_frame: Option<usize>,
    /// Evaluate only the first N images of the split.
    #[arg(long)]
    pub limit: Option<usize>,
    /// Each scene's fitted SMPL moved rigidly onto its source views' masks before rendering:
    /// on (the model's `[data] smpl_alignment` settings, else the defaults) or off (default:
    /// the model's `[data]` setting, off where it has none). A novel pose's reference frame
    /// keeps its stored fit either way.
    #[arg(long, value_parser = parse_switch)]
    pub smpl_alignment: Option<bool>,
    /// Iterations of the SMPL pose refinement after the rigid alignment (turns the alignment
    /// on; 0: rigid only; default: the model's `[data] smpl_alignment` setting).
    #[arg(long)]
    pub smpl_pose_iterations: Option<usize>,
    #[command(flatten)]
    pub lpips: LpipsArgs,
    /// Also score every image against the same view of this dataset root (same subjects,
    /// frames and cameras): a synthetic set generated with the same spec but without the mask
    /// flaw holds the image the flawed ground truth stands for. Adds `psnr_truth`,
    /// `ssim_truth` and `psnr_ibr_truth` to the diagnostics.
    #[arg(long)]
    pub truth_data: Option<PathBuf>,
    /// Skip the grid and blend-weight PNGs.
    #[arg(long)]
    pub no_pictures: bool,
    #[command(flatten)]
    pub stage_times: StageTimesArgs,
    /// Output folder.
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(Serialize)]
struct Mean {
    images: usize,
    psnr: f64,
    ssim: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    lpips: Option<f64>,
    diagnostics: BlendDiagnostics,
}

impl From<EvalSummary> for Mean {
    fn from(s: EvalSummary) -> Self {
        Mean {
            images: s.images,
            psnr: s.psnr,
            ssim: s.ssim,
            lpips: s.lpips,
            diagnostics: s.diagnostics,
        }
    }
}

#[derive(Serialize)]
struct ImageRow<'a> {
    #[serde(flatten)]
    result: &'a ImageResult,
    stage_ms: BTreeMap<String, f64>,
}

#[derive(Serialize)]
struct Metrics<'a> {
    model: PathBuf,
    model_step: u64,
    data: PathBuf,
    split: &'static str,
    task: &'static str,
    adaptive: RenderOptions,
    /// The SMPL alignment's settings (`None`: off; each image lists its correction).
    smpl_alignment: Option<SmplAlignment>,
    /// Novel pose: the source frame given on the command line (`None`: each subject's first).
    reference_frame: Option<usize>,
    samples: usize,
    /// Whether each image's stages were timed (not with `--no-stage-times`).
    stage_times: bool,
    /// The LPIPS network and files, when LPIPS was scored.
    lpips: Option<LpipsFiles>,
    overall: Mean,
    subjects: BTreeMap<String, Mean>,
    images: Vec<ImageRow<'a>>,
}

fn task_name(task: TaskArg) -> &'static str {
    match task {
        TaskArg::NovelView => "novel_view",
        TaskArg::NovelPose => "novel_pose",
    }
}

pub fn run(args: &EvalArgs) -> anyhow::Result<()> {
    let loaded = LoadedModel::open(&args.model)?;
    let samples = loaded.samples(&args.model);
    let adaptive = loaded.render_options(&args.model)?;
    let split = args.split.split();
    let task = match args.task {
        TaskArg::NovelView => EvalTask::NovelView,
        TaskArg::NovelPose => EvalTask::NovelPose {
            reference_frame: args.ref_frame,
        },
    };
    let data_config = data_config(args, &loaded, split)?;
    let root = data_config.root.clone();
    let data = loaded.open_split(&data_config, split)?;
    let items = eval_items(&data, split, task, args.limit)?;
    if items.is_empty() {
        anyhow::bail!(
            "{}: the `{}` split has no images to evaluate",
            root.display(),
            split.name()
        );
    }
    let pictures = args.out.join("pictures");
    let folder = if args.no_pictures {
        &args.out
    } else {
        &pictures
    };
    std::fs::create_dir_all(folder).with_context(|| format!("creating {}", folder.display()))?;
    let lpips = args
        .lpips
        .load(loaded.run.train.lpips.as_ref(), &loaded.device)?;
    let bar = progress_bar(items.len() as u64, "eval");
    let results = loaded.evaluate(
        &data,
        split,
        &items,
        EvalOptions {
            task,
            samples,
            chunk: loaded.chunk(&args.model, samples, &adaptive),
            timed: args.stage_times.timed(),
            render: adaptive,
            lpips: lpips.as_ref().map(|(_, net)| net.clone()),
            truth: args.truth_data.as_deref().map(|root| {
                Arc::new(TruthData::new(
                    root,
                    DatasetConfig {
                        ratio: data_config.ratio,
                        ..DatasetConfig::for_format(data_config.format)
                    },
                ))
            }),
        },
        &mut |e| {
            bar.inc(1);
            bar.set_message(format!("{:.2} dB", e.result.psnr));
            if args.no_pictures {
                return Ok(());
            }
            save_evaluated(&pictures, &e).map_err(|err| EvalError::Output(err.to_string()))
        },
    )?;
    bar.finish_and_clear();
    let overall = EvalSummary::of(&results)
        .context("no image was evaluated (novel pose skips the reference frame itself)")?;
    let mut by_subject: BTreeMap<String, Vec<ImageResult>> = BTreeMap::new();
    for r in &results {
        by_subject
            .entry(r.subject.clone())
            .or_default()
            .push(r.clone());
    }
    let subjects: BTreeMap<String, Mean> = by_subject
        .iter()
        .filter_map(|(k, v)| EvalSummary::of(v).map(|s| (k.clone(), s.into())))
        .collect();
    let metrics = Metrics {
        model: loaded.path.clone(),
        model_step: loaded.step,
        data: root.clone(),
        split: split.name(),
        task: task_name(args.task),
        adaptive,
        smpl_alignment: data_config.smpl_alignment,
        reference_frame: args.ref_frame,
        samples,
        stage_times: args.stage_times.timed(),
        lpips: lpips.as_ref().map(|(files, _)| files.clone()),
        overall: overall.into(),
        subjects,
        images: results
            .iter()
            .map(|r| ImageRow {
                result: r,
                stage_ms: r.times.milliseconds(),
            })
            .collect(),
    };
    write_json(&args.out.join("metrics.json"), &metrics)?;
    write_text(&args.out.join("metrics.csv"), &metrics_csv(&results))?;

    let task_title = match args.task {
        TaskArg::NovelView => "novel view",
        TaskArg::NovelPose => "novel pose",
    };
    let lpips_name = lpips
        .as_ref()
        .map(|(files, _)| format!(" ({})", files.net.name()))
        .unwrap_or_default();
    let intro = format!(
        "# Evaluation: {task_title}, split `{}`\n\nModel `{}` (step {}), data `{}`, {samples} samples per ray.\n\n| subject | images | PSNR (dB) | SSIM | LPIPS{lpips_name} |\n|---|---:|---:|---:|---:|\n",
        split.name(),
        loaded.path.display(),
        loaded.step,
        root.display()
    );
    let md = report_markdown(intro, &by_subject, &overall);
    write_text(&args.out.join("report.md"), &md)?;
    println!(
        "{}",
        serde_json::json!({
            "split": split.name(),
            "task": task_name(args.task),
            "images": overall.images,
            "psnr": overall.psnr,
            "ssim": overall.ssim,
            "lpips": overall.lpips,
            "lpips_net": lpips.as_ref().map(|(files, _)| files.net.name()),
            "diagnostics": overall.diagnostics,
            "out": args.out,
        })
    );
    Ok(())
}

/// The model's data settings with the command line's: `--data`, `--smpl`, the SMPL alignment
/// switches, and `--subjects` (held-out people of the test split, with their input views).
fn data_config(
    args: &EvalArgs,
    loaded: &LoadedModel,
    split: EvalSplit,
) -> anyhow::Result<DataConfig> {
    let mut data_config = loaded.data_config(args.data.as_deref(), args.smpl.as_deref());
    match args.smpl_alignment {
        Some(true) => {
            data_config
                .smpl_alignment
                .get_or_insert_with(SmplAlignment::default);
        }
        Some(false) => data_config.smpl_alignment = None,
        None => {}
    }
    if let Some(iterations) = args.smpl_pose_iterations {
        if args.smpl_alignment == Some(false) {
            anyhow::bail!(
                "--smpl-pose-iterations refines the alignment: not with --smpl-alignment off"
            );
        }
        data_config
            .smpl_alignment
            .get_or_insert_with(SmplAlignment::default)
            .pose_iterations = iterations;
    }
    if !args.subjects.is_empty() {
        if split != EvalSplit::UnseenSubjects {
            anyhow::bail!("--subjects names held-out people: use it with --split test");
        }
        data_config.protocol = ProtocolName::Subjects;
        data_config.split = Some(SubjectSplit {
            train: Vec::new(),
            test: args.subjects.clone(),
            input_views: (!args.input_views.is_empty()).then(|| args.input_views.clone()),
            train_frames: None,
            test_frame_stride: 1,
        });
    }
    Ok(data_config)
}

/// `metrics.csv`: one line per image.
fn metrics_csv(results: &[ImageResult]) -> String {
    let mut csv = String::from(
        "subject,frame,reference_frame,target_view,input_views,psnr,ssim,lpips,rays,point_evaluations,colour_evaluations,seconds\n",
    );
    for r in results {
        let views: Vec<String> = r.input_views.iter().map(|v| v.to_string()).collect();
        let _ = writeln!(
            csv,
            "{},{},{},{},{},{:.6},{:.6},{},{},{},{},{:.4}",
            r.subject,
            r.frame,
            r.reference_frame,
            r.target_view,
            views.join(" "),
            r.psnr,
            r.ssim,
            r.lpips.map(|l| format!("{l:.6}")).unwrap_or_default(),
            r.rays,
            r.point_evaluations,
            r.colour_evaluations,
            r.seconds
        );
    }
    csv
}

/// `report.md`: after `intro` (the title and the table's head), a row per subject and the
/// overall one, then the blend diagnostics' table.
fn report_markdown(
    intro: String,
    by_subject: &BTreeMap<String, Vec<ImageResult>>,
    overall: &EvalSummary,
) -> String {
    let lpips_cell = |l: Option<f64>| l.map(|l| format!("{l:.4}")).unwrap_or_else(|| "-".into());
    let mut md = intro;
    for (name, v) in by_subject {
        if let Some(s) = EvalSummary::of(v) {
            let _ = writeln!(
                md,
                "| {name} | {} | {:.2} | {:.4} | {} |",
                s.images,
                s.psnr,
                s.ssim,
                lpips_cell(s.lpips)
            );
        }
    }
    let _ = writeln!(
        md,
        "| **all** | {} | **{:.2}** | **{:.4}** | **{}** |\n\nPSNR over `mask_at_box`, SSIM and LPIPS (when weights were given: `--lpips-*` or the model's `train.lpips`) on its bounding-rectangle crop (NHP/NIA protocol). Pictures: `pictures/*_grid.png` (sources | prediction | ground truth | error, black to white = 0 to {ERROR_MAP_MAX} mean absolute error) `pictures/*_parts.png` (NeRF colour C0 | IBR-only composite | prediction | ground truth | opacity) and `pictures/*_blend.png` (blend weights: NeRF colour, then source views).",
        overall.images,
        overall.psnr,
        overall.ssim,
        lpips_cell(overall.lpips)
    );
    let mut rows: Vec<(String, BlendDiagnostics)> = by_subject
        .iter()
        .filter_map(|(name, v)| EvalSummary::of(v).map(|s| (name.clone(), s.diagnostics)))
        .collect();
    rows.push(("**all**".into(), overall.diagnostics));
    md.push('\n');
    md.push_str(&diagnostics_table(&rows));
    md
}
