//! Source holes, a training augmentation of the blend (switchable, `train.source_holes`; not in
//! the paper).
//!
//! Under a segmentation network's masks a source view loses parts of the person: small holes,
//! an eroded outline, a hand or foot. The source images are black outside their masks, so
//! such a view passes black into the blend where the target shows the person, and F_B must
//! learn to trust the views that agree. In the flawed training data that lesson is rare and
//! confounded: the target is cut by its own flawed mask too. With this augmentation each source
//! view of a training scene is, with probability `probability`, given 1 to 3 black discs
//! (radius 3-8 % of the image's shorter side) centred on its person pixels; the target is left
//! as it is, so where one view went black the loss rewards the views that did not.
//! Inference never punches holes.

use nia_data::rng::Rng;
use nia_data::scene::SourceView;

/// Radius of a hole as a share of the image's shorter side, `[min, max)`.
pub const HOLE_RADIUS_SHARE: (f32, f32) = (0.03, 0.08);
/// Most holes in one view.
pub const MAX_HOLES: usize = 3;

/// Which source views get holes, and with which seed.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SourceHoles {
    /// Probability that a source view gets holes, in [0, 1].
    pub probability: f32,
    /// Seed of the draws (the trainer derives it from the run's seed and the scene's index).
    pub seed: u64,
}

impl SourceHoles {
    /// Punches the holes into `views` (image and mask set to 0 inside each disc). Returns the
    /// number of views that got holes. A view without person pixels is left as it is.
    ///
    /// # Shapes
    /// - each view's `image`: `[3, H, W]` planar; `mask`: `[H * W]`
    pub fn apply(&self, views: &mut [SourceView]) -> usize {
        let mut rng = Rng::new(self.seed);
        let mut holed = 0;
        for view in views.iter_mut() {
            if rng.uniform() >= self.probability {
                continue;
            }
            let (w, h) = (view.camera.width as usize, view.camera.height as usize);
            let person: Vec<usize> = (0..w * h).filter(|&p| view.mask[p] > 0.5).collect();
            if person.is_empty() {
                continue;
            }
            let holes = 1 + rng.below(MAX_HOLES);
            let side = w.min(h) as f32;
            for _ in 0..holes {
                let centre = person[rng.below(person.len())];
                let (cx, cy) = ((centre % w) as f32, (centre / w) as f32);
                let share = HOLE_RADIUS_SHARE.0
                    + rng.uniform() * (HOLE_RADIUS_SHARE.1 - HOLE_RADIUS_SHARE.0);
                punch_disc(view, w, h, cx, cy, share * side);
            }
            holed += 1;
        }
        holed
    }
}

/// Sets image and mask to 0 at the pixels whose centres lie within `radius` of `(cx, cy)`.
fn punch_disc(view: &mut SourceView, w: usize, h: usize, cx: f32, cy: f32, radius: f32) {
    let x0 = (cx - radius).floor().max(0.0) as usize;
    let y0 = (cy - radius).floor().max(0.0) as usize;
    let x1 = ((cx + radius).ceil() as usize).min(w - 1);
    let y1 = ((cy + radius).ceil() as usize).min(h - 1);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let (dx, dy) = (x as f32 - cx, y as f32 - cy);
            if dx * dx + dy * dy <= radius * radius {
                let p = y * w + x;
                view.mask[p] = 0.0;
                for c in 0..3 {
                    view.image[c * w * h + p] = 0.0;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::{Mat3, Vec3};
    use nia_data::geometry::camera::Camera;

    fn view(w: usize, h: usize) -> SourceView {
        // The person: the middle half of the image, grey.
        let mask: Vec<f32> = (0..w * h)
            .map(|p| {
                let (x, y) = (p % w, p / w);
                (x >= w / 4 && x < 3 * w / 4 && y >= h / 4 && y < 3 * h / 4) as u8 as f32
            })
            .collect();
        let image = (0..3).flat_map(|_| mask.iter().map(|&m| 0.5 * m)).collect();
        SourceView {
            camera: Camera {
                k: Mat3::from_cols_array(&[
                    100.0,
                    0.0,
                    0.0,
                    0.0,
                    100.0,
                    0.0,
                    w as f32 / 2.0,
                    h as f32 / 2.0,
                    1.0,
                ]),
                r: Mat3::IDENTITY,
                t: Vec3::ZERO,
                dist: [0.0; 5],
                width: w as u32,
                height: h as u32,
            },
            image,
            mask,
            vertex_visibility: vec![1.0; 4],
        }
    }

    #[test]
    fn holes_black_out_person_pixels_only_where_drawn_and_repeat_with_the_seed() {
        let (w, h) = (64, 48);
        let originals: Vec<SourceView> = (0..3).map(|_| view(w, h)).collect();
        let mut views = originals.clone();
        let holes = SourceHoles {
            probability: 1.0,
            seed: 7,
        };
        assert_eq!(holes.apply(&mut views), 3);
        for (v, o) in views.iter().zip(&originals) {
            let before: f32 = o.mask.iter().sum();
            let after: f32 = v.mask.iter().sum();
            let lost = (before - after) / before;
            // 1-3 discs of radius 3-8 % of 48 px (1.4-3.8 px): a few to ~45 pixels each.
            assert!(lost > 0.0 && lost < 0.2, "share of the person lost {lost}");
            for p in 0..w * h {
                // Nothing outside the person changes; a pixel is black exactly where the mask
                // was taken away.
                assert!(v.mask[p] <= o.mask[p]);
                for c in 0..3 {
                    let (now, was) = (v.image[c * w * h + p], o.image[c * w * h + p]);
                    if v.mask[p] == o.mask[p] {
                        assert_eq!(now, was);
                    } else {
                        assert_eq!(now, 0.0);
                    }
                }
            }
        }
        let mut again = originals.clone();
        holes.apply(&mut again);
        for (a, b) in again.iter().zip(&views) {
            assert_eq!(a.image, b.image);
        }
    }

    #[test]
    fn probability_zero_leaves_every_view_and_an_empty_view_is_skipped() {
        let mut views = vec![view(32, 32)];
        let original = views.clone();
        let none = SourceHoles {
            probability: 0.0,
            seed: 1,
        };
        assert_eq!(none.apply(&mut views), 0);
        assert_eq!(views[0].image, original[0].image);
        let mut empty = vec![view(32, 32)];
        empty[0].mask.iter_mut().for_each(|m| *m = 0.0);
        let all = SourceHoles {
            probability: 1.0,
            seed: 1,
        };
        assert_eq!(all.apply(&mut empty), 0);
    }
}
