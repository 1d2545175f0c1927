//! The one way every command renders a view: [`prepare_scene`] (or [`prepare_pose`] for another
//! pose of a prepared scene) encodes the scene with what the [`RenderOptions`] ask of it, then
//! [`render_view`] casts the target camera's rays and renders the image.
//!
//! ```text
//! prepare_scene   NiaModel::encode -> occupancy grid (skipping) -> termination -> colour
//!                 culling -> visual hull                                  (once per scene)
//! prepare_pose    NiaModel::encode_pose -> occupancy grid of the new pose (once per pose)
//! render_view     the per-render options (termination, culling, colour points, c0's scale,
//!                 the density baked once per pose) -> rays through the pixel footprints
//!                 (supersampling) -> render_image
//! ```
//!
//! Only the source views of the scene reach the render: a target view's image and mask are
//! never an input (the evaluation reads them to score the prediction, after it is made).

use std::sync::Arc;

use nia_data::body::reposing::Reposer;
use nia_data::geometry::camera::Camera;
use nia_data::geometry::rays::Aabb;
use nia_data::geometry::rays::RayBundle;
use nia_data::scene::SceneInput;

use super::image::{render_image_cancellable, ImageRenderOptions, RenderedImage};
use crate::error::ModelError;
use crate::model::NiaModel;
use crate::render_options::RenderOptions;
use crate::scene_encoding::SceneEncoding;
use crate::timing::{StageTimes, Stopwatch};

/// One target view of a prepared scene.
#[derive(Clone, Copy)]
pub struct TargetView<'a> {
    /// The target camera (its image size is the rendered image's).
    pub camera: &'a Camera,
    /// The body's ray box in the rendered pose: rays that miss it are background.
    pub body_box: &'a Aabb,
    /// `[H * W]` the pixels to render (the evaluation's `mask_at_box`); `None`: every pixel
    /// whose rays cross the box.
    pub pixels: Option<&'a [bool]>,
    /// Samples per ray, rays per network call, and whether to time the stages.
    pub image: ImageRenderOptions,
    /// Asked before every chunk of rays: true stops the render with
    /// [`ModelError::Cancelled`] (an interactive viewer drops a frame a newer request made
    /// stale). `None` renders to the end.
    pub cancelled: Option<&'a dyn Fn() -> bool>,
}

/// The per-scene pass of `input` with what `options` asks of it: empty-space skipping on the
/// rendered pose's mesh (`reposer`'s target pose, else the scene's own), early termination,
/// colour culling and visual-hull carving from the source masks. `times` charges the encoder
/// and body-volume stages.
pub fn prepare_scene(
    model: &NiaModel,
    input: &SceneInput,
    reposer: Option<Arc<Reposer>>,
    options: &RenderOptions,
    device: &burn::prelude::Device,
    times: Option<&mut StageTimes>,
) -> Result<SceneEncoding, ModelError> {
    let posed_vertices = match &reposer {
        Some(r) => r.target_vertices(),
        None => &input.body.vertices[..],
    };
    let occupancy = options.occupancy(posed_vertices, &input.body.faces)?;
    model
        .encode(input, reposer, device, times)?
        .with_occupancy(occupancy)
        .with_termination(options.termination())
        .with_colour_culling(options.culling())
        .with_colour_points(options.colour_points())
        .with_c0_weight_scale(options.c0_scale())
        .with_visual_hull(input, options.visual_hull, options.hull_body_erode_px)
}

/// `base` (a [`prepare_scene`] of the reference pose) rendered in `reposer`'s target pose: the
/// body volume rebuilt on the target vertices, the occupancy grid of the target pose's mesh,
/// and the rest (termination, culling, the hull of the source views) carried over.
pub fn prepare_pose(
    model: &NiaModel,
    base: &SceneEncoding,
    reposer: Arc<Reposer>,
    options: &RenderOptions,
    times: Option<&mut StageTimes>,
) -> Result<SceneEncoding, ModelError> {
    let occupancy = options.occupancy(reposer.target_vertices(), &base.geometry.faces)?;
    Ok(model
        .encode_pose(base, reposer, times)?
        .with_occupancy(occupancy))
}

/// Renders `view` of `scene` (prepared with [`prepare_scene`] / [`prepare_pose`]) with
/// `options.supersample` x `options.supersample` rays per pixel. `progress(done, total)` is
/// called after every chunk of rays.
pub fn render_view(
    model: &NiaModel,
    scene: &SceneEncoding,
    view: &TargetView<'_>,
    options: &RenderOptions,
    progress: &mut dyn FnMut(usize, usize),
) -> Result<RenderedImage, ModelError> {
    let camera = view.camera;
    // What may change from render to render of one prepared scene (the viewer's drag frames
    // against its resting frames): termination, culling, colour points, c0's scale and the
    // baked density, baked on the first render that asks for it.
    let scene = scene
        .clone()
        .with_termination(options.termination())
        .with_colour_culling(options.culling())
        .with_colour_points(options.colour_points())
        .with_c0_weight_scale(options.c0_scale());
    // The bake's stages are charged to the image that paid for it (timed renders).
    let mut bake_times = StageTimes::default();
    let grid = match options.density_grid() {
        Some(cell) => {
            let device = scene.images.device();
            let times = view.image.timed.then_some(&mut bake_times);
            let mut watch = Stopwatch::new(times, &device);
            Some(model.baked_density(&scene, view.body_box, cell, &mut watch)?)
        }
        None => None,
    };
    let scene = scene.with_density_grid(grid);
    let rays = RayBundle::through_pixel_footprints(
        camera,
        view.body_box,
        view.pixels,
        options.supersample,
    );
    render_image_cancellable(
        model,
        &scene,
        &rays,
        [camera.width as usize, camera.height as usize],
        view.image,
        progress,
        view.cancelled.unwrap_or(&|| false),
    )?
    .map(|mut image| {
        image.times.merge(&bake_times);
        image
    })
    .ok_or(ModelError::Cancelled)
}
