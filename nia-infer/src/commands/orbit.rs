//! `nia-infer orbit`: a 360-degree turn around the subject of one frame, on the ring of the
//! dataset's calibrated cameras ([`nia_data::geometry::orbit::Ring`]), rendered from a few
//! source views: PNG frames, an animated GIF and, where `ffmpeg` is installed, an MP4. The
//! scene is encoded once; every orbit view reuses it.

use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::Context;
use clap::Args;
use nia_data::geometry::orbit::Ring;
use nia_eval::pictures::{rgb8, save_gif, save_png};
use serde::Serialize;

use crate::output::{progress_bar, write_json};
use crate::session::{RenderSession, SessionArgs, SessionReport};

#[derive(Args, Debug)]
pub struct OrbitArgs {
    #[command(flatten)]
    pub session: SessionArgs,
    /// Frame index (position in `annots['ims']`).
    #[arg(long, default_value_t = 0)]
    pub frame: usize,
    /// Views around the full turn.
    #[arg(long, default_value_t = 36)]
    pub steps: usize,
    /// Frames per second of the GIF and the MP4.
    #[arg(long, default_value_t = 12)]
    pub fps: u32,
    /// Output folder: orbit_XXX.png, orbit.gif, orbit.mp4 (with ffmpeg), orbit.json.
    #[arg(long)]
    pub out: PathBuf,
}

#[derive(Serialize)]
struct Report {
    #[serde(flatten)]
    session: SessionReport,
    frame: usize,
    steps: usize,
    fps: u32,
    /// Ring radius and camera height above the body centre, metres.
    radius_m: f32,
    height_m: f32,
    gif: String,
    /// `None` without ffmpeg.
    mp4: Option<String>,
    encode_seconds: f64,
    seconds_per_view: f64,
    point_evaluations_per_view: f64,
}

pub fn run(args: &OrbitArgs) -> anyhow::Result<()> {
    if args.steps == 0 {
        anyhow::bail!("--steps must be at least 1");
    }
    if args.fps == 0 {
        anyhow::bail!("--fps must be at least 1");
    }
    let session = RenderSession::open(&args.session)?;
    let opened = &session.opened;
    let scene = session.scene(args.frame)?;
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("creating {}", args.out.display()))?;

    let cameras = &opened.subject().cameras;
    let ring = Ring::of(cameras, scene.body_box.centre())
        .with_context(|| format!("the camera ring of {}", opened.dir.display()))?;
    let orbit = ring.orbit(args.steps, &cameras[0])?;

    let started = std::time::Instant::now();
    let encoding = session.prepare(&scene, None)?;
    let encode_seconds = started.elapsed().as_secs_f64();

    let bar = progress_bar(orbit.len() as u64, "orbit");
    let started = std::time::Instant::now();
    let mut frames = Vec::with_capacity(orbit.len());
    let mut points = 0u64;
    for (k, camera) in orbit.iter().enumerate() {
        let img = session
            .render(&encoding, camera, &scene.body_box, false, &mut |_, _| {})
            .with_context(|| format!("rendering orbit view {k}"))?;
        points += img.point_evaluations;
        let picture = rgb8(&img.rgb, img.width, img.height);
        save_png(&args.out.join(format!("orbit_{k:03}.png")), &picture)?;
        frames.push(picture);
        bar.inc(1);
    }
    bar.finish_and_clear();
    let seconds_per_view = started.elapsed().as_secs_f64() / orbit.len() as f64;
    let gif = "orbit.gif";
    save_gif(&args.out.join(gif), &frames, 1000 / args.fps)?;
    let mp4 = encode_mp4(&args.out, args.fps)?;
    if mp4.is_none() {
        eprintln!("ffmpeg not found: orbit.mp4 not written (the GIF and the PNG frames are)");
    }
    let report = Report {
        session: session.report(),
        frame: args.frame,
        steps: args.steps,
        fps: args.fps,
        radius_m: ring.radius,
        height_m: ring.height,
        gif: gif.into(),
        mp4,
        encode_seconds,
        seconds_per_view,
        point_evaluations_per_view: points as f64 / orbit.len() as f64,
    };
    write_json(&args.out.join("orbit.json"), &report)?;
    println!("{}", serde_json::to_string_pretty(&report)?);
    Ok(())
}

/// `out/orbit.mp4` from the PNG frames with ffmpeg (H.264, yuv420p, even size), or `None`
/// when no `ffmpeg` is on the PATH. A failing ffmpeg is an error with its message.
fn encode_mp4(out: &Path, fps: u32) -> anyhow::Result<Option<String>> {
    let probe = Command::new("ffmpeg").arg("-version").output();
    if !probe.is_ok_and(|o| o.status.success()) {
        return Ok(None);
    }
    let name = "orbit.mp4";
    let result = Command::new("ffmpeg")
        .args(["-y", "-loglevel", "error", "-framerate"])
        .arg(fps.to_string())
        .arg("-i")
        .arg(out.join("orbit_%03d.png"))
        .args([
            "-vf",
            "pad=ceil(iw/2)*2:ceil(ih/2)*2",
            "-pix_fmt",
            "yuv420p",
        ])
        .arg(out.join(name))
        .output()
        .context("running ffmpeg")?;
    if !result.status.success() {
        anyhow::bail!(
            "ffmpeg could not write {}: {}",
            out.join(name).display(),
            String::from_utf8_lossy(&result.stderr).trim()
        );
    }
    Ok(Some(name.into()))
}
