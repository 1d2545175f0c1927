//! `nia-infer render`: novel views of one frame of a subject from a few source views. The
//! scene (encoder features, body volume, visibility) is built once and reused by every target
//! camera and every chunk of rays; rays that miss the body's box are never sent to the network.

use std::collections::BTreeMap;
use std::path::PathBuf;

use anyhow::Context;
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use nia_model::image_render::{render_image, ImageRays, ImageRenderOptions};
use nia_model::scene::SceneGeometry;
use nia_model::timing::StageTimes;
use nia_train::train_loop::scene_input;
use serde::Serialize;

use crate::model_load::{LoadedModel, ModelArgs};
use crate::pictures::{blend_weight_maps, grey8, rgb8, save_png};
use crate::subject_scene::{parse_views, OpenedSubject, SubjectArgs, ViewList};

#[derive(Args, Debug)]
pub struct RenderArgs {
    #[command(flatten)]
    pub model: ModelArgs,
    #[command(flatten)]
    pub subject: SubjectArgs,
    /// Frame index (position in `annots['ims']`).
    #[arg(long)]
    pub frame: usize,
    /// Source cameras, e.g. 0,7,15.
    #[arg(long, value_parser = parse_views)]
    pub views: ViewList,
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
    pub seconds: f64,
    /// Milliseconds per stage (this image's rendering; the scene's encoding is reported once).
    pub stage_ms: BTreeMap<String, f64>,
}

#[derive(Serialize)]
struct Report {
    model: PathBuf,
    subject: PathBuf,
    frame: usize,
    views: Vec<usize>,
    samples: usize,
    chunk: usize,
    adaptive: nia_model::adaptive::AdaptiveConfig,
    /// Per-scene work (encoder, body volume), done once for all targets.
    encode_seconds: f64,
    encode_stage_ms: BTreeMap<String, f64>,
    images: Vec<ImageReport>,
}

/// Milliseconds per stage that took any time.
pub fn stage_ms(times: &StageTimes) -> BTreeMap<String, f64> {
    nia_model::timing::Stage::ALL
        .iter()
        .map(|&s| (s.name().to_string(), times.get(s).as_secs_f64() * 1e3))
        .filter(|(_, ms)| *ms > 0.0)
        .collect()
}

pub fn progress_bar(len: u64, what: &str) -> ProgressBar {
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(&format!(
            "{{spinner}} {what} [{{elapsed_precise}}] {{bar:30}} {{pos}}/{{len}} (eta {{eta}}) {{msg}}"
        ))
        .expect("static progress template"),
    );
    bar
}

pub fn run(args: &RenderArgs) -> anyhow::Result<()> {
    let views: Vec<usize> = args.views.0.clone();
    let targets: Vec<usize> = args.targets.0.clone();
    let loaded = LoadedModel::open(&args.model)?;
    let samples = loaded.samples(&args.model);
    let opened = OpenedSubject::open(&args.subject, &loaded.run)?;
    opened.check_views("--targets", &targets)?;
    let scene = opened.scene(args.frame, &views)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;

    let started = std::time::Instant::now();
    let mut encode_times = StageTimes::default();
    let input = scene_input(&scene, &opened.source.faces);
    let geometry = SceneGeometry::new(&input, &loaded.config)?;
    let adaptive = loaded.adaptive(&args.model);
    let occupancy = adaptive.occupancy(&scene.vertices, &opened.source.faces)?;
    let encoding = loaded
        .model
        .encode_scene_timed(
            &input,
            &geometry,
            None,
            &loaded.device,
            Some(&mut encode_times),
        )?
        .with_occupancy(occupancy);
    let encode_seconds = started.elapsed().as_secs_f64();

    let mut images = Vec::new();
    for &target in &targets {
        let camera = opened.camera(target);
        let rays = ImageRays::new(&camera, &scene.body_box, None);
        let bar = progress_bar(rays.pixels.len() as u64, &format!("view {target:>2}"));
        let t0 = std::time::Instant::now();
        let img = render_image(
            &loaded.model,
            &encoding,
            &geometry,
            None,
            &rays,
            ImageRenderOptions {
                samples,
                chunk: args.model.chunk,
                timed: true,
            },
            &loaded.device,
            &mut |done, _| bar.set_position(done as u64),
        )?;
        bar.finish_and_clear();
        let seconds = t0.elapsed().as_secs_f64();
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
            "view {target}: {} rays of {} pixels, {} network points, {:.2} s",
            img.rays,
            w * h,
            img.point_evaluations,
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
            seconds,
            stage_ms: stage_ms(&img.times),
        });
    }
    let report = Report {
        model: loaded.path.clone(),
        subject: args.subject.data.clone(),
        frame: args.frame,
        views,
        samples,
        chunk: args.model.chunk,
        adaptive,
        encode_seconds,
        encode_stage_ms: stage_ms(&encode_times),
        images,
    };
    let path = args.out.join("render.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {}", path.display()))?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}
