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
