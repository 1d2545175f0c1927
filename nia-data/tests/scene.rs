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

    fn hull() -> VisualHull {
        VisualHull::new(&[&left_half()], SIZE, SIZE).unwrap()
    }

    #[test]
    fn inside_the_mask_reads_one_and_outside_reads_zero() {
        let h = hull();
        assert_eq!(h.inside(0, Vec2::new(3.0, 8.0)), 1.0, "on the person");
        assert_eq!(h.inside(0, Vec2::new(12.0, 8.0)), 0.0, "off the person");
    }

    #[test]
    fn the_read_is_bilinear_across_the_outline() {
        let h = hull();
        // Column 7 is the person's last, column 8 the first empty one.
        for (u, expected) in [(7.0, 1.0), (7.25, 0.75), (7.5, 0.5), (8.0, 0.0)] {
            let got = h.inside(0, Vec2::new(u, 8.3));
            assert!((got - expected).abs() < 1e-6, "u = {u}: {got}");
        }
    }

    #[test]
    fn a_view_that_does_not_see_the_point_does_not_carve_it() {
        let h = hull();
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
    fn bad_masks_are_errors_naming_the_view_and_what_was_expected() {
        let short = vec![1.0f32; SIZE * SIZE - 1];
        let err = VisualHull::new(&[&left_half(), &short], SIZE, SIZE).unwrap_err();
        assert!(err.to_string().contains("views[1].mask"), "{err}");
        for bad in [f32::NAN, 1.5, -0.1] {
            let mut m = left_half();
            m[37] = bad;
            let err = VisualHull::new(&[&m], SIZE, SIZE).unwrap_err();
            assert!(err.to_string().contains("views[0].mask[37]"), "{err}");
        }
        let err = VisualHull::new(&[], 0, SIZE).unwrap_err();
        assert!(err.to_string().contains("image size"), "{err}");
    }
}

/// The masks the visual hull reads: with the fitted body's silhouette counted as person
/// (`masks_with_body`), and bad masks refused.
mod source_masks {
    use nia_data::scene::SourceMasks;

    const SIZE: usize = 16;

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
        let err = SourceMasks::new("visual hull", &[&short], SIZE, SIZE).unwrap_err();
        let msg = err.to_string();
        assert!(
            msg.contains("visual hull") && msg.contains("views[0].mask"),
            "{msg}"
        );
    }
}
