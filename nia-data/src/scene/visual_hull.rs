//! Visual-hull carving of the density (not in the paper; `[render] visual_hull`, at evaluation
//! and inference only): how far inside all the source views' person masks a point projects.
//!
//! F_sigma reads the person's outline only through SMPL-anchored features and pixel features of
//! the masked source images, a few pixels wide after the encoder's strides, so on a person
//! whose clothes stand off the body by more or less than the training people's, the outline
//! it draws is the training people's average margin (the seed-8 person of docs/results.md is drawn
//! half a pixel fat). The masks are inputs the reader loads anyway and they state the outline
//! exactly: a point that projects outside the person in any source view is empty space (the
//! visual hull, Laurentini 1994). The carving multiplies the density by
//!
//! ```text
//! hull(x) = min_n sum_k a_k M_n(p_k)
//! ```
//!
//! with `p_k` the four pixels around x's projection in view n, `a_k` their bilinear weights and
//! `M_n` view n's mask (growing the masks by a margin was tried for noisy masks and did not
//! help: docs/robustness.md, "Tried and not kept"). Pixels outside the image read 1 (no evidence either
//! way), so a view that does not see a point never carves it. The hull is loose between the
//! source views (three views carve a hexagon around a round limb) and tight where a target ray
//! grazes the person along a source camera's line of sight: at the outline of a target view
//! opposite a source view, where the synthetic protocol's targets sit (on ZJU-MoCap's ring of
//! 21-23 cameras, a few targets are near-opposite a source view).
//!
//! A segmentation network's mask that lost a band or a hand would carve that part out of the
//! person in every target view; with `[render] hull_body_erode_px` the fitted body's silhouette,
//! shrunk by that many pixels, counts as person in each mask first
//! ([`super::masks_with_body`]).
//!
//! The carving is applied when rendering, not in training: a network trained with it no longer
//! has to place empty space next to the person itself, and some such runs left holes in the
//! person (docs/results.md, "Tried and not kept"). Where the hull says 0 the density is exactly 0, so empty-space
//! skipping leaves those samples out of the network.

use glam::{Vec2, Vec3};

use super::source_masks::{MaskError, SourceMasks};
use crate::geometry::camera::Camera;

/// The masks of the source views.
#[derive(Debug, Clone)]
pub struct VisualHull {
    masks: SourceMasks,
}

impl VisualHull {
    /// The hull of `masks` ([N][H * W] person masks in [0, 1], row-major, one image size).
    pub fn new(masks: &[&[f32]], width: usize, height: usize) -> Result<Self, MaskError> {
        Ok(VisualHull {
            masks: SourceMasks::new("visual hull", masks, width, height)?,
        })
    }

    /// Number of views N.
    pub fn num_views(&self) -> usize {
        self.masks.num_views()
    }

    /// `hull(x)` of the module docs for the world point `x`, in [0, 1]: the least of
    /// [`Self::inside`] over the views, `cameras` ([N], the source cameras in view order)
    /// projecting it; views beyond the shorter of the two lists are not read. A view behind
    /// whose camera `x` lies does not carve it.
    pub fn carving(&self, cameras: &[Camera], x: Vec3) -> f32 {
        cameras
            .iter()
            .take(self.num_views())
            .enumerate()
            .map(|(view, camera)| match camera.project(x) {
                Some((uv, _depth)) => self.inside(view, uv),
                None => 1.0,
            })
            .fold(1.0, f32::min)
    }

    /// How far inside view `view`'s mask the projection `uv` (pixels, OpenCV centres
    /// at integer coordinates) lies, in [0, 1]: the bilinear read of the four pixels around
    /// it, pixels outside the image reading 1. A non-finite projection reads 1 as well: a
    /// point behind the camera or at its centre is not seen by the view, which then says
    /// nothing about it.
    pub fn inside(&self, view: usize, uv: Vec2) -> f32 {
        self.masks.read(view, uv, 1.0)
    }
}
