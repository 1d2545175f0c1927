//! One scene loaded on the calling thread (what each of the loader's workers runs,
//! [`crate::dataset::loader`]): the stored SMPL fit and the source images, the fit moved onto
//! the source masks when asked for, the body the network reads (the fit jittered for training),
//! every source view's vertex visibility, the target (training rays or the whole image), and
//! warm-ups of the process-wide geometry memos the training step reads.

use glam::Vec3;

use crate::body::SmplParams;
use crate::dataset::loader::{
    LoadedView, LoaderConfig, LoaderError, Scene, SceneRequest, SceneSource, SceneTarget,
    TargetKind,
};
use crate::dataset::sampling::sample_rays;
use crate::dataset::smpl_jitter::jitter_smpl;
use crate::dataset::vis_cache::{self, VisibilityQuery};
use crate::dataset::{DatasetError, Subject, ViewImage};
use crate::fitting::align::{align_fit, AlignedFit, AlignmentView};
use crate::fitting::SmplAlignment;
use crate::geometry::occupancy_memo::shared_grid;
use crate::geometry::rays::{mask_at_box, Aabb};
use crate::geometry::sparse::shared_pyramid;
use crate::geometry::surface_memo::shared_surface;
use crate::rng::Rng;
use crate::scene::vertices_in_smpl_frame;

/// Fork of a request's seed that draws its SMPL jitter (the ray sampling uses the seed itself).
const JITTER_FORK: u64 = 0x5a17;

/// Loads one scene on the calling thread.
pub fn load_scene(
    source: &SceneSource,
    request: &SceneRequest,
    index: usize,
    config: &LoaderConfig,
) -> Result<Scene, LoaderError> {
    let subject = requested_subject(source, request, index)?;
    let frame = request.frame;
    let vertices = stored_fit(subject, frame, &source.faces)?;
    let mut params = subject.load_params(frame)?;
    let vertices_path = subject.vertices_path(frame)?;
    let images = request
        .input_views
        .iter()
        .map(|&view| subject.load_view(frame, view).map(|image| (view, image)))
        .collect::<Result<Vec<_>, _>>()?;
    let body_box_of = |body: &[Vec3]| {
        config.box_padding.body_box(body).ok_or_else(|| {
            DatasetError::field(
                &vertices_path,
                "<array>",
                "a non-empty finite vertex set",
                "none",
            )
        })
    };
    // The metrics' region (`mask_at_box`) stays the stored fit's box, as the protocol has it.
    let fit_box = body_box_of(&vertices)?;
    // The stored fit moved onto the source masks (`None`: not asked for).
    let aligned = match &config.smpl_alignment {
        Some(alignment) => {
            let aligned = align_to_sources(
                source,
                subject,
                request,
                (&vertices, &params),
                &images,
                alignment,
            )?;
            params = aligned.params.clone();
            Some(aligned)
        }
        None => None,
    };
    let alignment = aligned.as_ref().map(|a| a.rigid);
    let pose_refinement = aligned.as_ref().and_then(|a| a.pose);
    let aligned = aligned.map(|a| a.vertices.clone());
    let fit = aligned.as_ref().unwrap_or(&vertices);
    // The body the network reads: for training scenes, the fit moved by the SMPL jitter
    // (`None`: the fit). Visibility stays the fit's.
    let moved = (request.target == TargetKind::Rays && config.smpl_jitter_m > 0.0).then(|| {
        let mut moved = fit.clone();
        let mut rng = Rng::new(request.seed).fork(JITTER_FORK);
        jitter_smpl(&mut moved, &mut params, config.smpl_jitter_m, &mut rng);
        moved
    });
    let body = moved.as_ref().unwrap_or(fit);
    let body_box = body_box_of(body)?;
    // The cache holds the stored fit's visibility; an aligned fit's is computed afresh.
    let sources = source_views(
        source,
        (subject, frame),
        images,
        fit,
        aligned.is_none(),
        config.visibility_depth_tol_m,
    )?;
    let target = scene_target(subject, request, config, &body_box, &fit_box)?;
    let vertices = moved.or(aligned).unwrap_or(vertices);
    warm_shared_geometry(request, config, &vertices, &source.faces, &params);
    Ok(Scene {
        index,
        subject: subject.name.clone(),
        frame,
        vertices,
        params,
        body_box,
        sources,
        target_view: request.target_view,
        target,
        alignment,
        pose_refinement,
    })
}

/// The subject `request` names, refused when out of range (`index`: the request's place in
/// its list, for the message).
fn requested_subject<'a>(
    source: &'a SceneSource,
    request: &SceneRequest,
    index: usize,
) -> Result<&'a Subject, LoaderError> {
    source
        .subjects
        .get(request.subject)
        .ok_or_else(|| LoaderError::Request {
            index,
            msg: format!(
                "subject {} out of range ({} subjects)",
                request.subject,
                source.subjects.len()
            ),
        })
}

/// The stored SMPL fit of `frame` (`[V]` world metres), refused when its vertex count is not
/// the one the body model's `faces` use.
fn stored_fit(
    subject: &Subject,
    frame: usize,
    faces: &[[u32; 3]],
) -> Result<Vec<Vec3>, LoaderError> {
    let vertices = subject.load_vertices(frame)?;
    let expected = faces.iter().flatten().max().map_or(0, |&m| m as usize + 1);
    if vertices.len() != expected {
        return Err(LoaderError::VertexCount {
            vertices: subject.vertices_path(frame)?,
            stored: vertices.len(),
            expected,
        });
    }
    Ok(vertices)
}

/// The stored fit (`vertices`, `params`) moved onto the masks of the source `images` by
/// `alignment` (training scenes take its training settings).
fn align_to_sources(
    source: &SceneSource,
    subject: &Subject,
    request: &SceneRequest,
    (vertices, params): (&[Vec3], &SmplParams),
    images: &[(usize, ViewImage)],
    alignment: &SmplAlignment,
) -> Result<std::sync::Arc<AlignedFit>, LoaderError> {
    let alignment = match request.target {
        TargetKind::Rays => alignment.for_training(),
        TargetKind::Image => *alignment,
    };
    let views: Vec<AlignmentView<'_>> = images
        .iter()
        .map(|(_, image)| AlignmentView {
            camera: &image.camera,
            mask: &image.mask,
        })
        .collect();
    align_fit(
        vertices,
        params,
        source.body_model.as_deref(),
        &views,
        &alignment,
    )
    .map_err(|source| LoaderError::Alignment {
        subject: subject.name.clone(),
        frame: request.frame,
        source,
    })
}

/// The source `images` of `frame` with the visibility of `fit`'s vertices in each, from the
/// source's cache when `cached` (the stored fit's) and it has one, else computed.
fn source_views(
    source: &SceneSource,
    (subject, frame): (&Subject, usize),
    images: Vec<(usize, ViewImage)>,
    fit: &[Vec3],
    cached: bool,
    depth_tol_m: f32,
) -> Result<Vec<LoadedView>, LoaderError> {
    let mut sources = Vec::with_capacity(images.len());
    for (view, image) in images {
        let query = VisibilityQuery {
            subject: &subject.name,
            frame,
            view,
            camera: &image.camera,
            vertices: fit,
            faces: &source.faces,
            depth_tol_m,
        };
        let visibility = match (&source.cache, cached) {
            (Some(cache), true) => cache.get_or_compute(&query)?,
            _ => vis_cache::compute(&query)?,
        };
        sources.push(LoadedView {
            view,
            image,
            visibility,
        });
    }
    Ok(sources)
}

/// The target of `request`: training rays of the target view sampled in `body_box`, or the
/// whole target image with the `mask_at_box` of the stored fit's `fit_box`.
fn scene_target(
    subject: &Subject,
    request: &SceneRequest,
    config: &LoaderConfig,
    body_box: &Aabb,
    fit_box: &Aabb,
) -> Result<SceneTarget, LoaderError> {
    let target_image = subject.load_view(request.frame, request.target_view)?;
    Ok(match request.target {
        TargetKind::Rays => {
            let mut rng = Rng::new(request.seed);
            let rays = sample_rays(
                &target_image.camera,
                &target_image.image,
                &target_image.mask,
                body_box,
                &config.sampling,
                &mut rng,
            )
            .map_err(|source| LoaderError::Sampling {
                subject: subject.name.clone(),
                frame: request.frame,
                view: request.target_view,
                source,
            })?;
            SceneTarget::Rays(rays)
        }
        TargetKind::Image => SceneTarget::Image {
            mask_at_box: mask_at_box(&target_image.camera, fit_box),
            image: target_image,
        },
    })
}

/// For training scenes, the geometry the step will ask the process-wide memos for, built now
/// on the worker (the band sampler's grid, the nearest-surface index, the body volume's
/// pyramid): only warm-ups, whose failures the step meets again, with their errors.
fn warm_shared_geometry(
    request: &SceneRequest,
    config: &LoaderConfig,
    vertices: &[Vec3],
    faces: &[[u32; 3]],
    params: &SmplParams,
) {
    if request.target != TargetKind::Rays {
        return;
    }
    if let Some(band) = config.band_grid {
        let _ = shared_grid(vertices, faces, band.threshold_m, band.cell_m);
    }
    let _ = shared_surface(vertices, faces);
    if let Some(volume) = config.body_volume {
        let smpl = vertices_in_smpl_frame(vertices, params.rh, params.th);
        if let Ok(voxel_box) = volume.grid.enclosing(&smpl) {
            if let Ok(pyramid) = shared_pyramid(&smpl, &voxel_box, volume.levels) {
                if volume.neighbour_maps {
                    pyramid.warm_neighbour_maps();
                }
            }
        }
    }
}
