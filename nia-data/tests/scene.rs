//! The per-scene geometry and the per-point inputs of the network: d_hat_n, projections.

use glam::Vec3;
use nia_data::scene::view_direction_feature;

/// f32 values computed along two paths: a few ulps of O(1) values.
const VALUE_TOL: f32 = 1e-6;

#[test]
fn view_direction_feature_is_difference_and_cosine() {
    assert_eq!(
        view_direction_feature(Vec3::Z, Vec3::Y),
        [0.0, -1.0, 1.0, 0.0]
    );
    let h = std::f32::consts::FRAC_1_SQRT_2;
    let got = view_direction_feature(Vec3::Z, Vec3::new(0.0, h, h));
    let expected = [0.0, -h, 1.0 - h, h];
    for (g, e) in got.iter().zip(expected) {
        assert!((g - e).abs() <= VALUE_TOL, "{got:?} vs {expected:?}");
    }
}

mod depth_test {
    use glam::{Vec2, Vec3};
    use nia_data::geometry::camera::Camera;
    use nia_data::scene::SourceDepth;

    const SIZE: u32 = 16;
    const TOL: f32 = 0.03;
    /// Camera depth of the occluder.
    const WALL_Z: f32 = 2.0;

    /// A camera at the origin looking down +z (f = SIZE: 1 pixel = 1/16 m at 1 m).
    fn camera() -> Camera {
        let f = SIZE as f32;
        Camera::look_at(Vec3::ZERO, Vec3::Z, Vec3::NEG_Y, f, f, SIZE, SIZE).unwrap()
    }

    /// A wall at z = 2 covering the image's left half (x < 0 in the world; the principal
    /// point is at u = 8, so pixel columns 0..=7 have their centres on it).
    fn depth() -> SourceDepth {
        let v = [
            Vec3::new(-10.0, -10.0, WALL_Z),
            Vec3::new(-0.0625, -10.0, WALL_Z),
            Vec3::new(-0.0625, 10.0, WALL_Z),
            Vec3::new(-10.0, 10.0, WALL_Z),
        ];
        SourceDepth::rasterise(&[camera()], &v, &[[0, 1, 2], [0, 2, 3]], TOL).unwrap()
    }

    #[test]
    fn a_point_behind_the_body_is_hidden_and_one_in_front_is_not() {
        let d = depth();
        let covered = Vec2::new(3.0, 8.0);
        assert_eq!(d.unhidden(0, covered, 3.0), 0.0, "behind the wall");
        assert_eq!(d.unhidden(0, covered, 1.5), 1.0, "in front of it");
        assert_eq!(
            d.unhidden(0, covered, WALL_Z + 0.5 * TOL),
            1.0,
            "within tol"
        );
        assert_eq!(d.unhidden(0, covered, WALL_Z + 2.0 * TOL), 0.0, "past tol");
    }

    #[test]
    fn empty_pixels_and_pixels_outside_the_image_pass() {
        let d = depth();
        assert_eq!(d.unhidden(0, Vec2::new(12.0, 8.0), 3.0), 1.0, "uncovered");
        assert_eq!(
            d.unhidden(0, Vec2::new(-5.0, 8.0), 3.0),
            1.0,
            "left of the image"
        );
        assert_eq!(
            d.unhidden(0, Vec2::new(30.0, 40.0), 3.0),
            1.0,
            "below the image"
        );
        assert_eq!(
            d.unhidden(0, Vec2::new(f32::NAN, 8.0), 1.0),
            0.0,
            "NaN projection"
        );
    }

    #[test]
    fn the_share_is_bilinear_across_an_occlusion_edge() {
        let d = depth();
        // Column 7 is the wall's last, column 8 the first empty one.
        for (u, expected) in [
            (7.0, 0.0),
            (7.25, 0.25),
            (7.5, 0.5),
            (7.75, 0.75),
            (8.0, 1.0),
        ] {
            let got = d.unhidden(0, Vec2::new(u, 8.3), 3.0);
            assert!(
                (got - expected).abs() < 1e-6,
                "u = {u}: {got} vs {expected}"
            );
        }
    }

    #[test]
    fn a_bad_tolerance_or_mixed_sizes_are_errors_naming_them() {
        let v = [Vec3::new(0.0, 0.0, 2.0), Vec3::X, Vec3::Y];
        for tol in [-0.01, f32::NAN, f32::INFINITY] {
            let err = SourceDepth::rasterise(&[camera()], &v, &[[0, 1, 2]], tol).unwrap_err();
            assert!(err.to_string().contains("tol_m"), "{err}");
        }
        let mut small = camera();
        small.width = SIZE / 2;
        let err = SourceDepth::rasterise(&[camera(), small], &v, &[[0, 1, 2]], TOL).unwrap_err();
        assert!(err.to_string().contains("cameras"), "{err}");
    }
}

mod visual_hull {
    use glam::Vec2;
    use nia_data::scene::VisualHull;

    const SIZE: usize = 16;

    /// A 16 x 16 mask whose columns 0..=7 are the person.
    fn left_half() -> Vec<f32> {
        (0..SIZE * SIZE)
            .map(|i| ((i % SIZE) < 8) as u8 as f32)
            .collect()
    }

    fn hull(dilate_px: usize) -> VisualHull {
        VisualHull::new(&[&left_half()], SIZE, SIZE, dilate_px).unwrap()
    }

    #[test]
    fn inside_the_mask_reads_one_and_outside_reads_zero() {
        let h = hull(0);
        assert_eq!(h.inside(0, Vec2::new(3.0, 8.0)), 1.0, "on the person");
        assert_eq!(h.inside(0, Vec2::new(12.0, 8.0)), 0.0, "off the person");
    }

    #[test]
    fn the_read_is_bilinear_across_the_outline() {
        let h = hull(0);
        // Column 7 is the person's last, column 8 the first empty one.
        for (u, expected) in [(7.0, 1.0), (7.25, 0.75), (7.5, 0.5), (8.0, 0.0)] {
            let got = h.inside(0, Vec2::new(u, 8.3));
            assert!((got - expected).abs() < 1e-6, "u = {u}: {got}");
        }
    }

    #[test]
    fn a_view_that_does_not_see_the_point_does_not_carve_it() {
        let h = hull(0);
        for uv in [
            Vec2::new(-5.0, 8.0),
            Vec2::new(40.0, 8.0),
            Vec2::new(12.0, -3.0),
            Vec2::new(f32::NAN, 8.0),
            Vec2::new(f32::INFINITY, f32::NEG_INFINITY),
        ] {
            assert_eq!(h.inside(0, uv), 1.0, "{uv:?}");
        }
    }

    #[test]
    fn dilation_moves_the_outline_out_by_whole_pixels() {
        let h = hull(2);
        assert_eq!(
            h.inside(0, Vec2::new(9.0, 8.0)),
            1.0,
            "column 9 is inside now"
        );
        assert_eq!(h.inside(0, Vec2::new(9.5, 8.0)), 0.5);
        assert_eq!(h.inside(0, Vec2::new(10.0, 8.0)), 0.0);
    }

    #[test]
    fn bad_masks_are_errors_naming_the_view_and_what_was_expected() {
        let short = vec![1.0f32; SIZE * SIZE - 1];
        let err = VisualHull::new(&[&left_half(), &short], SIZE, SIZE, 0).unwrap_err();
        assert!(err.to_string().contains("views[1].mask"), "{err}");
        for bad in [f32::NAN, 1.5, -0.1] {
            let mut m = left_half();
            m[37] = bad;
            let err = VisualHull::new(&[&m], SIZE, SIZE, 0).unwrap_err();
            assert!(err.to_string().contains("views[0].mask[37]"), "{err}");
        }
        let err = VisualHull::new(&[&left_half()], SIZE, SIZE, 1000).unwrap_err();
        assert!(err.to_string().contains("dilate_px"), "{err}");
        let err = VisualHull::new(&[], 0, SIZE, 0).unwrap_err();
        assert!(err.to_string().contains("image size"), "{err}");
    }
}

/// o_n's mask test (`SourceMasks::shows_person`): the mask as it is, bilinear, and nothing
/// seen where the view shows nothing (off the image, behind the camera).
mod mask_test {
    use glam::Vec2;
    use nia_data::scene::SourceMasks;

    const SIZE: usize = 16;

    /// A 16 x 16 mask whose columns 0..=7 are the person, with a one-pixel hole at (3, 8).
    fn left_half_with_hole() -> Vec<f32> {
        let mut m: Vec<f32> = (0..SIZE * SIZE)
            .map(|i| ((i % SIZE) < 8) as u8 as f32)
            .collect();
        m[8 * SIZE + 3] = 0.0;
        m
    }

    fn masks() -> SourceMasks {
        SourceMasks::new("o_n's mask test", &[&left_half_with_hole()], SIZE, SIZE, 0).unwrap()
    }

    #[test]
    fn the_person_reads_one_and_holes_and_background_read_zero() {
        let m = masks();
        assert_eq!(m.shows_person(0, Some(Vec2::new(2.0, 4.0))), 1.0);
        assert_eq!(
            m.shows_person(0, Some(Vec2::new(3.0, 8.0))),
            0.0,
            "the hole"
        );
        assert_eq!(m.shows_person(0, Some(Vec2::new(12.0, 8.0))), 0.0);
        // Half-way between the hole and the person beside it.
        let got = m.shows_person(0, Some(Vec2::new(3.5, 8.0)));
        assert!((got - 0.5).abs() < 1e-6, "{got}");
    }

    #[test]
    fn a_view_that_shows_nothing_at_the_point_does_not_see_it() {
        let m = masks();
        for uv in [
            Vec2::new(-5.0, 8.0),
            Vec2::new(2.0, -3.0),
            Vec2::new(2.0, 40.0),
            Vec2::new(f32::NAN, 8.0),
            Vec2::new(f32::INFINITY, f32::NEG_INFINITY),
        ] {
            assert_eq!(m.shows_person(0, Some(uv)), 0.0, "{uv:?}");
        }
        assert_eq!(m.shows_person(0, None), 0.0, "behind the camera");
        // Half a pixel off the image's left edge, on a person column: half the weight.
        let got = m.shows_person(0, Some(Vec2::new(-0.5, 4.0)));
        assert!((got - 0.5).abs() < 1e-6, "{got}");
    }

    /// The body's silhouette joins the masks before carving (`masks_with_body`): a wall over
    /// the image's left half (pixel columns 0..=7) as the body, and a mask of that half with
    /// a band cut across it (rows 6 and 7), as a segmentation network cuts one.
    #[test]
    fn the_body_fills_a_band_cut_from_the_mask_but_for_its_eroded_rim() {
        use glam::Vec3;
        use nia_data::geometry::camera::Camera;
        use nia_data::scene::masks_with_body;
        let f = SIZE as f32;
        let camera = Camera::look_at(
            Vec3::ZERO,
            Vec3::Z,
            Vec3::NEG_Y,
            f,
            f,
            SIZE as u32,
            SIZE as u32,
        )
        .unwrap();
        let wall = [
            Vec3::new(-10.0, -10.0, 2.0),
            Vec3::new(-0.0625, -10.0, 2.0),
            Vec3::new(-0.0625, 10.0, 2.0),
            Vec3::new(-10.0, 10.0, 2.0),
        ];
        let faces = [[0, 1, 2], [0, 2, 3]];
        let mask: Vec<f32> = (0..SIZE * SIZE)
            .map(|i| {
                let (x, y) = (i % SIZE, i / SIZE);
                (x < 8 && !(6..=7).contains(&y)) as u8 as f32
            })
            .collect();
        let cameras = [camera];
        let with = |erode| masks_with_body(&[&mask], &cameras, &wall, &faces, erode).unwrap();
        let full = &with(0)[0];
        let rim = &with(2)[0];
        for y in 0..SIZE {
            for x in 0..SIZE {
                let i = y * SIZE + x;
                let body = x < 8;
                assert_eq!(full[i], body as u8 as f32, "erode 0 at ({x}, {y})");
                // Eroded by 2 the body covers columns 0..=5: the band stays cut in 6 and 7.
                let expected = mask[i].max((x < 6) as u8 as f32);
                assert_eq!(rim[i], expected, "erode 2 at ({x}, {y})");
            }
        }
        let err = masks_with_body(&[&mask, &mask], &cameras, &wall, &faces, 0).unwrap_err();
        assert!(err.to_string().contains("one mask per camera"), "{err}");
        let short = vec![0.0f32; SIZE * SIZE - 1];
        let err = masks_with_body(&[&short], &cameras, &wall, &faces, 0).unwrap_err();
        assert!(err.to_string().contains("views[0].mask"), "{err}");
    }

    #[test]
    fn bad_masks_are_errors_naming_the_reader_and_the_view() {
        let short = vec![1.0f32; SIZE * SIZE - 1];
        let err = SourceMasks::new("o_n's mask test", &[&short], SIZE, SIZE, 0).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("o_n's mask test") && msg.contains("views[0].mask"),
            "{msg}"
        );
    }
}
