//! `nia-infer view`: an unseen person in the browser. The scene of the reference frame (its
//! source images, visibility and body volume) is encoded once; a pose of another frame is
//! the reposing path from it (cached for the last few poses); every request renders one
//! image from the orbit camera ([`nia_data::geometry::orbit::Ring::view`]) and can be dropped
//! between chunks when a newer request of the same client arrives.
//!
//! [`server`] serves the page ([`PAGE`]), the state, the renders and the source thumbnails.

pub mod server;

use std::collections::{BTreeMap, VecDeque};
use std::io::Cursor;
use std::sync::Arc;
use std::time::Instant;

use anyhow::Context;
use image::RgbImage;
use nia_data::body::reposing::Reposer;
use nia_data::body::SmplParams;
use nia_data::dataset::loader::Scene;
use nia_data::dataset::sampling::BoxPadding;
use nia_data::geometry::camera::Camera;
use nia_data::geometry::orbit::Ring;
use nia_data::geometry::rays::Aabb;
use nia_eval::pictures::{grey8, rgb8};
use nia_model::render_options::RenderOptions;
use nia_model::renderer::image::RenderedImage;
use nia_model::scene_encoding::SceneEncoding;
use nia_model::timing::StageTimes;
use serde::Serialize;

use crate::session::RenderSession;

/// The page, served at `/`.
pub const PAGE: &str = include_str!("page.html");

/// Pose encodings kept besides the reference frame's (each holds a body volume).
const POSE_CACHE: usize = 2;
/// Limits of the view parameters (radians for angles).
pub const MAX_ELEVATION: f32 = 1.4;
pub const ZOOM_RANGE: (f32, f32) = (0.3, 3.0);
pub const SCALE_RANGE: (f32, f32) = (0.05, 1.0);

/// What the view shows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Mode {
    /// The blended colour C.
    Color,
    /// The NeRF colour C0.
    Nerf,
    /// The blend weights: C0's in white, each source view's in its colour.
    Blend,
    /// Accumulated opacity.
    Opacity,
    /// Expected depth, near bright.
    Depth,
}

impl Mode {
    pub const ALL: [Mode; 5] = [
        Mode::Color,
        Mode::Nerf,
        Mode::Blend,
        Mode::Opacity,
        Mode::Depth,
    ];

    pub fn name(self) -> &'static str {
        match self {
            Mode::Color => "color",
            Mode::Nerf => "nerf",
            Mode::Blend => "blend",
            Mode::Opacity => "opacity",
            Mode::Depth => "depth",
        }
    }
}

/// The colours of the source views in the blend mode (and the thumbnails' borders).
pub const VIEW_COLOURS: [[f32; 3]; 6] = [
    [1.0, 0.25, 0.25],
    [0.25, 1.0, 0.25],
    [0.3, 0.45, 1.0],
    [1.0, 0.85, 0.2],
    [1.0, 0.3, 1.0],
    [0.2, 1.0, 1.0],
];

/// One render request, checked.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ViewRequest {
    /// Radians around the ring from the first camera.
    pub azimuth: f32,
    /// Radians above the cameras' own elevation, |e| <= [`MAX_ELEVATION`].
    pub elevation: f32,
    /// Distance relative to the ring's, in [`ZOOM_RANGE`].
    pub zoom: f32,
    /// The frame whose pose is shown (sources stay those of the reference frame).
    pub frame: usize,
    pub mode: Mode,
    /// Image size relative to the cameras', in [`SCALE_RANGE`].
    pub scale: f32,
    /// A frame of a drag: the fast mode ([`fast_samples`] samples per ray, one ray per
    /// pixel, the density baked per pose, [`FAST_COLOUR_POINTS`] coloured per ray); otherwise
    /// the model's samples and `[render]` settings, the picture the camera rests on.
    pub fast: bool,
}

/// Samples coloured per ray in the frames of a drag (`nia_model::renderer::colour_once`; 0:
/// every sample, as the model's own settings). K = 1 costs 0.01 dB at the drag's 8 samples on
/// the quickstart's clean 512-px set (seed 0) and 0.03 dB at 32 samples on set 61 (`zju_like`,
/// the main recipe's model), where it was chosen; on report set 62, 0.03 dB at 8 samples
/// (0.00 with the baked density) (docs/accuracy-time.md).
pub const FAST_COLOUR_POINTS: usize = 1;

/// The density a drag reads, baked once per pose on a grid of this spacing, metres
/// (`nia_model::renderer::density_grid`; the picture the camera rests on runs F_sigma at its
/// samples). 1 cm: -0.11 dB on the clean 512-px set, +0.04 dB on report set 62.
pub const FAST_DENSITY_GRID_M: f32 = 0.01;

/// The frames of a drag take the model's samples per ray divided by this ...
pub const FAST_SAMPLE_DIVISOR: usize = 4;
/// ... but at least this many (or the model's own, if fewer).
pub const FAST_MIN_SAMPLES: usize = 8;

/// Samples per ray in the frames of a drag for a model that renders with `samples`: a quarter,
/// at least [`FAST_MIN_SAMPLES`]. Chosen on the quickstart's clean 512-px set (generator seed 0,
/// 3 images: the tiny network 32 -> 8 samples -0.14 dB, 2.6x faster; the paper network 64 -> 16
/// -0.19 dB, 3.3x faster) and checked on report seed 51 `zju_like` (the main command's model,
/// 12 images, 32 -> 8: -0.03 dB) (docs/accuracy-time.md).
pub fn fast_samples(samples: usize) -> usize {
    (samples / FAST_SAMPLE_DIVISOR)
        .max(FAST_MIN_SAMPLES)
        .min(samples)
}

/// A rendered view and what it cost.
pub struct ViewFrame {
    pub png: Vec<u8>,
    pub stats: ViewStats,
}

/// What a view cost: shown under the picture.
#[derive(Debug, Clone, Serialize)]
pub struct ViewStats {
    pub width: u32,
    pub height: u32,
    pub rays: usize,
    /// Samples per ray (fewer in a drag's frames: [`fast_samples`]).
    pub samples: usize,
    pub point_evaluations: u64,
    /// Milliseconds of the whole request, of reposing set-up (0 for the reference pose or a
    /// cached one) and of each network stage.
    pub total_ms: f64,
    pub pose_ms: f64,
    pub stage_ms: BTreeMap<String, f64>,
}

/// The subject, the model and the encoded reference scene.
pub struct ViewerScene {
    /// The model, the subject and the `[render]` options.
    pub session: RenderSession,
    pub reference_frame: usize,
    scene: Scene,
    base: SceneEncoding,
    pub ring: Ring,
    like: Camera,
    poses: VecDeque<(usize, SceneEncoding, Aabb)>,
    /// Seconds to encode the reference scene.
    pub encode_seconds: f64,
}

impl ViewerScene {
    /// Opens and encodes the reference frame's scene from `views`.
    pub fn new(session: RenderSession, reference_frame: usize) -> anyhow::Result<Self> {
        let opened = &session.opened;
        let scene = session.scene(reference_frame)?;
        let cameras = &opened.subject().cameras;
        let ring = Ring::of(cameras, scene.body_box.centre())
            .with_context(|| format!("the camera ring of {}", opened.dir.display()))?;
        let like = cameras[0];
        let started = Instant::now();
        let base = session.prepare(&scene, None)?;
        Ok(ViewerScene {
            encode_seconds: started.elapsed().as_secs_f64(),
            session,
            reference_frame,
            scene,
            base,
            ring,
            like,
            poses: VecDeque::new(),
        })
    }

    /// Frames of the subject (the pose slider's range).
    pub fn num_frames(&self) -> usize {
        self.session.opened.subject().num_frames()
    }

    /// The source images as thumbnails (`index` into the session's views).
    pub fn source_png(&self, index: usize) -> Option<Vec<u8>> {
        let view = &self.scene.sources.get(index)?.image;
        let img = rgb8(&view.image, view.width() as usize, view.height() as usize);
        png_bytes(&img).ok()
    }

    /// The encoding and body box of `frame`'s pose (the reference frame's own, or reposed
    /// from it), and the milliseconds it took to set up.
    fn pose(&mut self, frame: usize) -> anyhow::Result<(SceneEncoding, Aabb, f64)> {
        if frame == self.reference_frame {
            return Ok((self.base.clone(), self.scene.body_box, 0.0));
        }
        if let Some((_, e, b)) = self.poses.iter().find(|(f, _, _)| *f == frame) {
            return Ok((e.clone(), *b, 0.0));
        }
        let started = Instant::now();
        let params = self.session.opened.subject().load_params(frame)?;
        let target = SmplParams {
            shapes: self.scene.params.shapes.clone(),
            ..params
        };
        let reposer = Arc::new(
            Reposer::new(&self.session.opened.body, &self.scene.params, &target)
                .with_context(|| format!("reposing to frame {frame}"))?,
        );
        let body_box = BoxPadding::nhp()
            .body_box(reposer.target_vertices())
            .with_context(|| format!("frame {frame}: the posed body has no finite vertices"))?;
        let encoding = self.session.prepare_pose(&self.base, reposer, None)?;
        if self.poses.len() >= POSE_CACHE {
            self.poses.pop_front();
        }
        self.poses.push_back((frame, encoding.clone(), body_box));
        Ok((encoding, body_box, started.elapsed().as_secs_f64() * 1e3))
    }

    /// Renders `request`, or `None` when `cancelled` said so before it was done.
    pub fn render(
        &mut self,
        request: &ViewRequest,
        cancelled: &dyn Fn() -> bool,
    ) -> anyhow::Result<Option<ViewFrame>> {
        let started = Instant::now();
        let camera = self.ring.view(
            request.azimuth,
            request.elevation,
            request.zoom,
            &self.like,
            request.scale,
        )?;
        let (encoding, body_box, pose_ms) = self.pose(request.frame)?;
        // The frames of a drag take one ray per pixel and a quarter of the samples per ray;
        // the picture the camera rests on takes the model's samples and `[render]` settings.
        let options = if request.fast {
            RenderOptions {
                supersample: 1,
                colour_points: FAST_COLOUR_POINTS,
                density_grid_m: FAST_DENSITY_GRID_M,
                ..self.session.options
            }
        } else {
            self.session.options
        };
        let mut view =
            self.session
                .target_view(&camera, &body_box, self.session.timed, Some(cancelled));
        if request.fast {
            view.image.samples = fast_samples(view.image.samples);
            view.image.chunk = self.session.chunk_for(view.image.samples, &options);
        }
        let Some(img) = self
            .session
            .render_with(&encoding, &view, &options, &mut |_, _| {})?
        else {
            return Ok(None);
        };
        let picture = picture(&img, request.mode);
        let png = png_bytes(&picture)?;
        let times: StageTimes = img.times.clone();
        Ok(Some(ViewFrame {
            png,
            stats: ViewStats {
                width: camera.width,
                height: camera.height,
                rays: img.rays,
                samples: view.image.samples,
                point_evaluations: img.point_evaluations,
                total_ms: started.elapsed().as_secs_f64() * 1e3,
                pose_ms,
                stage_ms: times.milliseconds(),
            },
        }))
    }
}

/// The picture of a mode.
pub fn picture(img: &RenderedImage, mode: Mode) -> RgbImage {
    let (w, h) = (img.width, img.height);
    match mode {
        Mode::Color => rgb8(&img.rgb, w, h),
        Mode::Nerf => rgb8(&img.rgb0, w, h),
        Mode::Opacity => grey8(&img.acc, w, h),
        Mode::Depth => {
            // Near bright, far dark, over the 2nd..98th percentile of the opaque pixels'
            // depths (a few hazy pixels would flatten a min..max scale).
            let mut seen: Vec<f32> = img
                .depth
                .iter()
                .zip(&img.acc)
                .filter(|(_, &a)| a > 0.5)
                .map(|(&d, _)| d)
                .collect();
            seen.sort_by(f32::total_cmp);
            let at = |q: f32| seen.get(((seen.len() as f32 - 1.0) * q) as usize).copied();
            let (near, far) = (at(0.02).unwrap_or(0.0), at(0.98).unwrap_or(1.0));
            let span = (far - near).max(1e-3);
            let v: Vec<f32> = img
                .depth
                .iter()
                .zip(&img.acc)
                .map(|(&d, &a)| {
                    if a > 0.05 {
                        0.15 + 0.85 * (1.0 - ((d - near) / span).clamp(0.0, 1.0))
                    } else {
                        0.0
                    }
                })
                .collect();
            grey8(&v, w, h)
        }
        Mode::Blend => {
            let k = img.blend_channels;
            let mut rgb = vec![0.0f32; w * h * 3];
            for p in 0..w * h {
                let weights = &img.blend_weights[p * k..p * k + k];
                for c in 0..3 {
                    let mut v = weights[0];
                    for (n, wv) in weights.iter().enumerate().skip(1) {
                        v += wv * VIEW_COLOURS[(n - 1) % VIEW_COLOURS.len()][c];
                    }
                    rgb[3 * p + c] = v;
                }
            }
            rgb8(&rgb, w, h)
        }
    }
}

fn png_bytes(img: &RgbImage) -> anyhow::Result<Vec<u8>> {
    let mut out = Vec::new();
    img.write_to(&mut Cursor::new(&mut out), image::ImageFormat::Png)
        .context("encoding a PNG")?;
    Ok(out)
}

#[cfg(test)]
mod fast_samples_tests {
    use super::*;

    #[test]
    fn a_drag_takes_a_quarter_of_the_samples_but_at_least_eight_and_never_more() {
        assert_eq!(fast_samples(64), 16);
        assert_eq!(fast_samples(32), 8);
        assert_eq!(fast_samples(16), 8);
        assert_eq!(fast_samples(8), 8);
        assert_eq!(fast_samples(4), 4);
        assert_eq!(fast_samples(1), 1);
    }
}
