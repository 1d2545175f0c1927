//! `nia-infer render`: novel views of one frame of a subject from a few source views. The
//! scene (encoder features, body volume, visibility) is built once and reused by every target
//! camera and every chunk of rays; rays that miss the body's box are never sent to the network.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use nia_eval::pictures::{blend_weight_maps, grey8, rgb8, save_png};
use nia_model::kernels::readback::readbacks;
use nia_model::render_options::RenderOptions;
use nia_model::timing::StageTimes;
use serde::Serialize;

use crate::output::{progress_bar, write_json};
use crate::session::{RenderSession, SessionArgs, SessionReport};
use crate::subject_scene::{parse_views, ViewList};

#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub session: SessionArgs,
    /// Frame index (position in `annots['ims']`).
    #[arg(long)]
    pub frame: usize,
    /// Target cameras to render, e.g. 3,5.
    #[arg(long, value_parser = parse_views)]
    pub targets: ViewList,
    /// Output folder for the PNGs and render.json.
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(Serialize)]
pub struct ImageReport {
    pub file: String,
    pub target_view: usize,
    pub width: usize,
    pub height: usize,
    /// Rays sent to the network (the others missed the body box).
    pub rays: usize,
    pub pixels: usize,
    pub point_evaluations: u64,
    /// Of those, the points whose colour was evaluated (colour culling skips the rest).
    pub colour_evaluations: u64,
    pub seconds: f64,
    /// Tensor reads of this image's render (on a GPU each is a wait for the device;
    /// `nia_model::kernels::readback::readbacks`).
    pub readbacks: u64,
    /// Milliseconds per stage (this image's rendering; the scene's encoding is reported once);
    /// empty with `--no-stage-times`.
    pub stage_ms: BTreeMap<String, f64>,
}

#[derive(Serialize)]
struct Report {
    #[serde(flatten)]
    session: SessionReport,
    frame: usize,
    chunk: usize,
    adaptive: RenderOptions,
    /// Whether the stages were timed (not with `--no-stage-times`).
    stage_times: bool,
    /// Per-scene work (encoder, body volume), done once for all targets.
    encode_seconds: f64,
    /// Tensor reads of the encoding.
    encode_readbacks: u64,
    encode_stage_ms: BTreeMap<String, f64>,
    images: Vec<ImageReport>,
}

pub fn run(args: &RenderArgs) -> anyhow::Result<()> {
    let targets: Vec<usize> = args.targets.0.clone();
    let session = RenderSession::open(&args.session)?;
    let opened = &session.opened;
    opened.check_views("--targets", &targets)?;
    let scene = session.scene(args.frame)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;

    let started = std::time::Instant::now();
    let encode_reads_before = readbacks();
    let timed = session.timed;
    let mut encode_times = StageTimes::default();
    let encoding = session.prepare(&scene, timed.then_some(&mut encode_times))?;
    let encode_seconds = started.elapsed().as_secs_f64();
    let encode_readbacks = readbacks() - encode_reads_before;

    let mut images = Vec::new();
    for &target in &targets {
        let camera = opened.camera(target);
        let bar = progress_bar(0, &format!("view {target:>2}"));
        let t0 = std::time::Instant::now();
        let reads_before = readbacks();
        let img = session.render(
            &encoding,
            &camera,
            &scene.body_box,
            timed,
            &mut |done, total| {
                bar.set_length(total as u64);
                bar.set_position(done as u64)
            },
        )?;
        bar.finish_and_clear();
        let seconds = t0.elapsed().as_secs_f64();
        let reads = readbacks() - reads_before;
        let stem = format!("frame{:04}_view{target:02}", args.frame);
        let (w, h) = (img.width, img.height);
        save_png(&args.out.join(format!("{stem}.png")), &rgb8(&img.rgb, w, h))?;
        save_png(
            &args.out.join(format!("{stem}_acc.png")),
            &grey8(&img.acc, w, h),
        )?;
        save_png(
            &args.out.join(format!("{stem}_blend.png")),
            &blend_weight_maps(&img.blend_weights, img.blend_channels, w, h),
        )?;
        eprintln!(
            "view {target}: {} rays of {} pixels, {} network points ({} coloured), {:.2} s",
            img.rays,
            w * h,
            img.point_evaluations,
            img.colour_evaluations,
            seconds
        );
        images.push(ImageReport {
            file: format!("{stem}.png"),
            target_view: target,
            width: w,
            height: h,
            rays: img.rays,
            pixels: w * h,
            point_evaluations: img.point_evaluations,
            colour_evaluations: img.colour_evaluations,
            seconds,
            readbacks: reads,
            stage_ms: img.times.milliseconds(),
        });
    }
    let report = Report {
        session: session.report(),
        frame: args.frame,
        chunk: session.chunk(),
        adaptive: session.options,
        stage_times: timed,
        encode_seconds,
        encode_readbacks,
        encode_stage_ms: encode_times.milliseconds(),
        images,
    };
    write_json(&args.out.join("render.json"), &report)?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}
