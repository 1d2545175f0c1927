//! `nia-infer animate`: the subject of a reference frame, seen through its source views,
//! reposed to the SMPL poses of other frames (or of a folder of params files) and rendered
//! from one camera: PNG frames and an animated GIF.
//!
//! The source images' feature maps are computed once; each pose rebuilds only the body volume
//! on the posed vertices ([`nia_model::NiaModel::encode_pose`]). The subject keeps the
//! reference frame's body shape (`shapes`): a pose's own shape coefficients are replaced by the
//! reference's, since the images show one person.

use std::path::PathBuf;
use std::sync::Arc;

use anyhow::Context;
use clap::Args;
use nia_data::body::reposing::Reposer;
use nia_data::body::SmplParams;
use nia_data::dataset::sampling::BoxPadding;
use nia_data::dataset::zju::read_params;
use nia_eval::pictures::{rgb8, save_gif, save_png};
use nia_model::timing::StageTimes;
use serde::Serialize;

use crate::output::{progress_bar, write_json};
use crate::session::{RenderSession, SessionArgs, SessionReport};
use crate::subject_scene::OpenedSubject;

#[derive(Args, Debug)]
pub struct AnimateArgs {
    #[command(flatten)]
    pub session: SessionArgs,
    /// The frame whose source images show the subject.
    #[arg(long)]
    pub ref_frame: usize,
    /// The camera to render from.
    #[arg(long, default_value_t = 0)]
    pub target: usize,
    /// Frames whose poses to take: `A..B` (B excluded), `A..=B`, or `A`.
    #[arg(long, value_parser = parse_frames, conflicts_with = "params", required_unless_present = "params")]
    pub poses: Option<FrameSpan>,
    /// A folder of SMPL params files (`*.npy` as in ZJU-MoCap's `params/`), in name order.
    #[arg(long)]
    pub params: Option<PathBuf>,
    /// GIF frame rate.
    #[arg(long, default_value_t = 10)]
    pub fps: u32,
    /// Output folder: pose_XXXX.png, animation.gif, animate.json.
    #[arg(long)]
    pub out: PathBuf,
}

/// A span of frame indices.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FrameSpan {
    pub start: usize,
    /// Exclusive.
    pub end: usize,
}

pub fn parse_frames(s: &str) -> Result<FrameSpan, String> {
    let bad = || format!("`{s}`: expected A..B, A..=B or A (frame indices)");
    let num = |t: &str| t.trim().parse::<usize>().map_err(|_| bad());
    let span = if let Some((a, b)) = s.split_once("..=") {
        FrameSpan {
            start: num(a)?,
            end: num(b)? + 1,
        }
    } else if let Some((a, b)) = s.split_once("..") {
        FrameSpan {
            start: num(a)?,
            end: num(b)?,
        }
    } else {
        let a = num(s)?;
        FrameSpan {
            start: a,
            end: a + 1,
        }
    };
    if span.end <= span.start {
        return Err(format!("`{s}`: the span is empty"));
    }
    Ok(span)
}

#[derive(Serialize)]
struct PoseReport {
    file: String,
    /// The frame the pose came from, or the params file.
    pose: String,
    rays: usize,
    point_evaluations: u64,
    seconds: f64,
    stage_ms: std::collections::BTreeMap<String, f64>,
}

#[derive(Serialize)]
struct Report {
    #[serde(flatten)]
    session: SessionReport,
    ref_frame: usize,
    target: usize,
    gif: String,
    /// Whether the stages were timed (not with `--no-stage-times`).
    stage_times: bool,
    poses: Vec<PoseReport>,
}

/// The poses to animate: (label, params).
fn poses(args: &AnimateArgs, opened: &OpenedSubject) -> anyhow::Result<Vec<(String, SmplParams)>> {
    if let Some(dir) = &args.params {
        let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
            .with_context(|| format!("reading the params folder {}", dir.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|x| x == "npy"))
            .collect();
        files.sort_by_key(|p| {
            let stem = p
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default();
            (stem.parse::<u64>().unwrap_or(u64::MAX), stem)
        });
        if files.is_empty() {
            anyhow::bail!("{}: no .npy params files", dir.display());
        }
        return files
            .into_iter()
            .map(|f| Ok((f.display().to_string(), read_params(&f)?)))
            .collect();
    }
    let span = args.poses.context("give --poses A..B or --params DIR")?;
    opened.check_frame("--poses", span.end - 1)?;
    (span.start..span.end)
        .map(|f| Ok((format!("frame {f}"), opened.subject().load_params(f)?)))
        .collect()
}

pub fn run(args: &AnimateArgs) -> anyhow::Result<()> {
    let session = RenderSession::open(&args.session)?;
    let opened = &session.opened;
    opened.check_views("--target", &[args.target])?;
    opened.check_frame("--ref-frame", args.ref_frame)?;
    let poses = poses(args, opened)?;
    let scene = session.reference_scene(args.ref_frame)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;

    let base = session.prepare(&scene, None)?;
    let camera = opened.camera(args.target);
    let bar = progress_bar(poses.len() as u64, "poses");
    let mut frames = Vec::new();
    let mut reports = Vec::new();
    for (i, (label, params)) in poses.iter().enumerate() {
        let started = std::time::Instant::now();
        let mut times = StageTimes::default();
        let target = SmplParams {
            shapes: scene.params.shapes.clone(),
            ..params.clone()
        };
        let reposer = Arc::new(
            Reposer::new(&opened.body, &scene.params, &target)
                .with_context(|| format!("reposing to {label}"))?,
        );
        let body_box = BoxPadding::nhp()
            .body_box(reposer.target_vertices())
            .with_context(|| format!("{label}: the posed body has no finite vertices"))?;
        let encoding = session.prepare_pose(&base, reposer, session.timed.then_some(&mut times))?;
        let img = session
            .render(&encoding, &camera, &body_box, session.timed, &mut |_, _| {})
            .with_context(|| format!("rendering {label}"))?;
        times.merge(&img.times);
        let file = format!("pose_{i:04}.png");
        let picture = rgb8(&img.rgb, img.width, img.height);
        save_png(&args.out.join(&file), &picture)?;
        frames.push(picture);
        reports.push(PoseReport {
            file,
            pose: label.clone(),
            rays: img.rays,
            point_evaluations: img.point_evaluations,
            seconds: started.elapsed().as_secs_f64(),
            stage_ms: times.milliseconds(),
        });
        bar.inc(1);
    }
    bar.finish_and_clear();
    let gif = "animation.gif";
    save_gif(&args.out.join(gif), &frames, 1000 / args.fps.max(1))?;
    let report = Report {
        session: session.report(),
        ref_frame: args.ref_frame,
        target: args.target,
        gif: gif.into(),
        stage_times: session.timed,
        poses: reports,
    };
    write_json(&args.out.join("animate.json"), &report)?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}
