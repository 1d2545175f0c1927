//! One subject's frames: its pose at each frame, what the capture writes about it (the true
//! SMPL fit and cameras, or the flawed ones of [`super::capture`]), and every camera's image
//! and mask (of the clothed body, with hair and loose garments off SMPL when that flaw is on),
//! rendered in parallel and written in the ZJU-MoCap layout.

use std::path::Path;

use glam::Vec3;
use rayon::prelude::*;

use super::cameras::{camera_ring, RingSpec};
use super::capture::colour::ColourResponse;
use super::capture::loose_geometry::LooseGeometry;
use super::capture::masks::degrade_mask;
use super::capture::smpl_fit::SmplFitError;
use super::clothing::{clothe, vertex_normals};
use super::keypoints::{self, KeypointRig};
use super::render::{render_view, RenderedView, SurfaceAttributes};
use super::subject::{Subject, SubjectDesign};
use super::{capture, writer, SynthError, SynthEvent, SynthSpec};
use crate::body::{BodyModel, SmplParams};
use crate::geometry::camera::Camera;
use crate::rng::Rng;

/// The per-frame state every camera of that frame renders.
struct PosedFrame {
    /// [V] clothed world vertices, metres.
    clothed: Vec<Vec3>,
    /// [V] unit normals of the clothed surface.
    normals: Vec<Vec3>,
    /// The hands and feet, world metres (where a degraded mask may lose one).
    extremities: Vec<Vec3>,
    /// With `--keypoints`: the true body's `[K]` 3D keypoints and `[V]` vertices (world
    /// metres), before any SMPL-fit flaw.
    keypoint_body: Option<(Vec<Option<Vec3>>, Vec<Vec3>)>,
}

/// SMPL joints of the hands and feet.
const EXTREMITY_JOINTS: [usize; 4] = [10, 11, 22, 23];

/// SMPL parameters of `subject` at `frame`.
fn frame_params(spec: &SynthSpec, subject: &Subject, frame: usize) -> SmplParams {
    let t_s = frame as f32 / spec.fps;
    SmplParams {
        poses: subject.poses(t_s),
        shapes: subject.design.betas.clone(),
        rh: subject.rh(t_s),
        th: subject.th(t_s),
    }
}

/// The images written so far of all `total`, and where each is reported.
pub(super) struct ImageProgress<'a> {
    pub done: usize,
    pub total: usize,
    pub report: &'a mut dyn FnMut(SynthEvent),
}

/// What the capture of one subject draws once: the camera ring, and the flaws of what it
/// writes (cameras, SMPL fit, colour, masks, loose geometry) and of its keypoint detector.
/// Each draws from its own fork of the subject's generator, so the clean output does not
/// change.
struct SubjectCapture {
    /// The true cameras, which render the images.
    cameras: Vec<Camera>,
    /// The cameras the capture writes (miscalibrated with the calibration flaw).
    written_cameras: Vec<Camera>,
    /// How each camera sees colour.
    responses: Vec<ColourResponse>,
    /// The SMPL fit the capture writes, per frame.
    fit: SmplFitError,
    /// The masks' degradation, forked per image.
    mask_rng: Rng,
    /// Hair and loose garments off the body.
    loose: LooseGeometry,
    /// The detector's keypoints (`--keypoints`), from a fork no other file uses.
    rig: Option<KeypointRig>,
    keypoint_rng: Rng,
}

impl SubjectCapture {
    /// The capture of `subject` (id `id`) as `spec` asks, from `rng`.
    fn draw(
        spec: &SynthSpec,
        body: &BodyModel,
        subject: &Subject,
        id: u32,
        rng: &Rng,
    ) -> Result<Self, SynthError> {
        // The ring looks at the body centre at frame 0 (the body walks in place).
        let p0 = frame_params(spec, subject, 0);
        let centre_canonical = Vec3::new(
            0.0,
            0.5 * (subject.frame.head_top_y + subject.frame.sole_y),
            0.0,
        );
        let centre = crate::body::rodrigues(p0.rh) * centre_canonical + p0.th;
        let ring = RingSpec {
            count: spec.cameras,
            size: spec.size,
            centre,
            body_height_m: subject.body_height_m,
        };
        let cameras: Vec<Camera> = camera_ring(&ring, &mut rng.fork(2))
            .map_err(|source| SynthError::Camera { id, source })?;
        let flaws = spec.capture;
        let written_cameras: Vec<Camera> = cameras
            .iter()
            .enumerate()
            .map(|(c, cam)| {
                let mut r = rng.fork(3).fork(c as u64);
                capture::calibration::miscalibrate(cam, flaws.calibration, &mut r)
            })
            .collect();
        let responses: Vec<ColourResponse> = (0..spec.cameras)
            .map(|c| ColourResponse::draw(flaws.colour, &mut rng.fork(5).fork(c as u64)))
            .collect();
        let fit = SmplFitError::draw(
            flaws.smpl_fit,
            spec.frames,
            spec.fps,
            subject.design.betas.len(),
            &mut rng.fork(4),
        );
        let mask_rng = rng.fork(6);
        let loose = LooseGeometry::draw(
            flaws.geometry,
            &subject.frame,
            &subject.design.cut,
            &subject.canonical,
            &subject.parts,
            &mut rng.fork(7),
        );
        Ok(SubjectCapture {
            cameras,
            written_cameras,
            responses,
            fit,
            mask_rng,
            loose,
            rig: spec.keypoints.map(|k| KeypointRig::new(k, body)),
            keypoint_rng: rng.fork(8),
        })
    }
}

/// One subject's frames as [`generate_subject`] writes them: the spec, the body model, the
/// subject and its capture, and the folder.
struct FrameWriter<'a> {
    spec: &'a SynthSpec,
    body: &'a BodyModel,
    id: u32,
    dir: &'a Path,
    subject: &'a Subject,
    capture: &'a SubjectCapture,
}

impl FrameWriter<'_> {
    /// The body at `frame`, with the fit (params and vertices) the capture writes for it.
    fn pose(&self, frame: usize) -> Result<PosedFrame, SynthError> {
        let (spec, body, subject, dir) = (self.spec, self.body, self.subject, self.dir);
        let params = frame_params(spec, subject, frame);
        let body_posed = body.lbs(&params);
        // The fit the capture writes; the images show the true body.
        let fitted = self.capture.fit.perturb(frame, &params);
        writer::write_params(
            dir,
            frame,
            &fitted.poses,
            fitted.rh,
            fitted.th,
            &fitted.shapes,
        )?;
        if fitted == params {
            writer::write_vertices(dir, frame, &body_posed.vertices)?;
        } else {
            writer::write_vertices(dir, frame, &body.lbs(&fitted).vertices)?;
        }
        let body_normals = vertex_normals(&body_posed.vertices, &body.faces);
        // Hair and loose garments off the body (exactly the garments at level 0): in the
        // images only, the written SMPL stays the body.
        let offsets = self
            .capture
            .loose
            .clothing_offsets_m(&subject.offsets_m, frame as f32 / spec.fps);
        let clothed = clothe(&body_posed.vertices, &body_normals, &offsets);
        writer::write_clothed_vertices(dir, frame, &clothed)?;
        let normals = vertex_normals(&clothed, &body.faces);
        let extremities = EXTREMITY_JOINTS
            .iter()
            .filter_map(|&j| body_posed.joints.get(j).copied())
            .collect();
        let keypoint_body = self.capture.rig.as_ref().map(|rig| {
            let points = rig.points_3d(&body_posed.vertices, &body_posed.joints);
            (points, body_posed.vertices.clone())
        });
        Ok(PosedFrame {
            clothed,
            normals,
            extremities,
            keypoint_body,
        })
    }

    /// `camera`'s image, mask (and keypoints) of the posed `frame`, rendered and written.
    fn write_view(
        &self,
        frame: usize,
        camera: usize,
        posed: &PosedFrame,
    ) -> Result<(), SynthError> {
        let (spec, dir, capture) = (self.spec, self.dir, self.capture);
        let render_err = |source| SynthError::Render {
            id: self.id,
            frame,
            camera,
            source,
        };
        let surface = SurfaceAttributes {
            canonical: &self.subject.canonical,
            parts: &self.subject.parts,
            frame: &self.subject.frame,
            cut: &self.subject.design.cut,
            look: &self.subject.design.look,
        };
        let mut view = render_view(
            &capture.cameras[camera],
            spec.supersample,
            &posed.clothed,
            &posed.normals,
            &self.body.faces,
            &surface,
        )
        .map_err(render_err)?;
        capture.responses[camera].apply(&mut view.rgb, view.width, view.height);
        if spec.capture.masks > 0.0 {
            self.degrade_mask(&mut view, frame, camera, posed);
        }
        writer::write_jpeg(
            &writer::image_path(dir, camera, frame),
            &view.rgb,
            view.width,
            view.height,
        )?;
        writer::write_mask(
            &writer::mask_path(dir, camera, frame),
            &view.mask,
            view.width,
            view.height,
        )?;
        if let (Some(rig), Some((points, vertices))) = (&capture.rig, &posed.keypoint_body) {
            let mut r = capture
                .keypoint_rng
                .fork((frame * spec.cameras + camera) as u64);
            let kp = rig
                .observe(
                    &capture.cameras[camera],
                    points,
                    vertices,
                    &self.body.faces,
                    &mut r,
                    (frame, camera, &capture.keypoint_rng.fork(u64::MAX)),
                )
                .map_err(render_err)?;
            keypoints::write(&keypoints::keypoints_path(dir, camera, frame), &kp)?;
        }
        Ok(())
    }

    /// The mask flaw on `camera`'s `view` of `frame`: the hands and feet may be lost, with a
    /// radius of a twentieth of the person's height.
    fn degrade_mask(
        &self,
        view: &mut RenderedView,
        frame: usize,
        camera: usize,
        posed: &PosedFrame,
    ) {
        let spec = self.spec;
        let extremities: Vec<[f32; 2]> = posed
            .extremities
            .iter()
            .filter_map(|&x| self.capture.cameras[camera].project(x))
            .map(|(uv, _)| uv.to_array())
            .collect();
        let mut r = self
            .capture
            .mask_rng
            .fork((frame * spec.cameras + camera) as u64);
        let radius = person_height_px(&view.mask, view.width) / 20.0;
        degrade_mask(
            &mut view.mask,
            view.width,
            view.height,
            &extremities,
            radius.max(1.0),
            spec.capture.masks,
            &mut r,
        );
    }
}

/// Draws subject `id` from `rng` and writes its frames under `dir`: every camera's image and
/// mask of every frame, rendered in parallel, what the capture writes about them, and one
/// [`SynthEvent::ImageWritten`] per image to `progress`.
pub(super) fn generate_subject(
    spec: &SynthSpec,
    body: &BodyModel,
    id: u32,
    dir: &Path,
    rng: &mut Rng,
    progress: &mut ImageProgress<'_>,
) -> Result<(), SynthError> {
    let design = SubjectDesign::draw(id, &mut rng.fork(1));
    let subject = Subject::prepare(body, design)?;
    let capture = SubjectCapture::draw(spec, body, &subject, id, rng)?;
    writer::create_subject_dirs(dir, spec.cameras)?;
    if capture.rig.is_some() {
        keypoints::create_dirs(dir, spec.cameras)?;
    }
    writer::write_annots(dir, &capture.written_cameras, spec.frames)?;
    let frames = FrameWriter {
        spec,
        body,
        id,
        dir,
        subject: &subject,
        capture: &capture,
    };
    // Frames per parallel batch: enough (frame, camera) pairs to keep every thread busy.
    let threads = rayon::current_num_threads().max(1);
    let batch = (2 * threads).div_ceil(spec.cameras).max(1);
    let all: Vec<usize> = (0..spec.frames).collect();
    for chunk in all.chunks(batch) {
        let posed: Vec<PosedFrame> = chunk
            .par_iter()
            .map(|&frame| frames.pose(frame))
            .collect::<Result<_, SynthError>>()?;
        let jobs: Vec<(usize, usize)> = (0..chunk.len())
            .flat_map(|f| (0..spec.cameras).map(move |c| (f, c)))
            .collect();
        jobs.par_iter()
            .map(|&(f, camera)| frames.write_view(chunk[f], camera, &posed[f]))
            .collect::<Result<Vec<()>, SynthError>>()?;
        for &(f, camera) in &jobs {
            progress.done += 1;
            (progress.report)(SynthEvent::ImageWritten {
                subject_id: id,
                frame: chunk[f],
                camera,
                done: progress.done,
                total: progress.total,
            });
        }
    }
    Ok(())
}

/// Rows of `mask` ([H * W], `width` wide) that hold some of the person, pixels.
fn person_height_px(mask: &[u8], width: u32) -> f32 {
    mask.chunks(width.max(1) as usize)
        .filter(|row| row.iter().any(|&m| m > 0))
        .count() as f32
}
