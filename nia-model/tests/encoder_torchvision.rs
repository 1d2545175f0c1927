#![allow(deprecated)] // Device::ndarray(): burn deprecates it, the user asked for it; it is the reference CPU backend.

//! `ImageEncoder::load_torchvision` on state dicts written by real torch
//! (scripts/fixtures/make_resnet_fixture.py): parameters arrive bit for bit, the encoder's
//! pyramid matches torch's, and bad files give typed errors naming the file.

mod common;

use std::path::{Path, PathBuf};

use burn::prelude::*;
use burn::tensor::DType;
use nia_model::encoder::import::EncoderLoadError;
use nia_model::encoder::{ImageEncoder, ImageEncoderConfig};

/// The fixture's trunk width (conv1 3 -> 8, layer2 16, layer3 32).
const FIXTURE_BASE_WIDTH: usize = 8;

/// Our f32 forward against torch's float64 reference: f32 rounding in convolutions of up to
/// 3 * 7 * 7 = 147 and 32 * 9 = 288 terms summed in a different order, through seven conv+BN
/// stages, on activations up to ~2.5. Measured: 7e-7 (burn-ndarray), 9e-7 (torch's own f32
/// forward); the bound leaves an order of magnitude for other backends' summation orders.
const FORWARD_TOLERANCE: f32 = 1e-5;

fn fixture(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/fixtures/resnet")
        .join(name)
}

/// An `.npy` fixture as (shape, values).
fn npy(name: &str) -> (Vec<usize>, Vec<f32>) {
    let array = nia_data::formats::npy::read(&fixture(name)).unwrap();
    let values = array.to_f32_vec().unwrap();
    (array.shape, values)
}

fn values<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    t.into_data().to_vec::<f32>().unwrap()
}

fn tiny_encoder(device: &Device) -> ImageEncoder {
    ImageEncoderConfig::new()
        .with_base_width(FIXTURE_BASE_WIDTH)
        .init(device)
}

/// The tiny encoder with the fixture's trunk on `device`.
fn fixture_encoder(device: &Device) -> ImageEncoder {
    tiny_encoder(device)
        .load_torchvision(&fixture("resnet_tiny.pth"))
        .unwrap()
}

/// The file an import error names.
fn named_file(err: &EncoderLoadError) -> &Path {
    use EncoderLoadError::*;
    match err {
        Read { file, .. } | ShapeMismatch { file, .. } | UnsupportedDType { file, .. } => file,
        MissingTensors { file, .. } | UnexpectedTensors { file, .. } | Tensor { file, .. } => file,
    }
}

/// The error of loading `path` into `encoder`, printed; it names `path`, in its fields and in
/// its message.
fn load_error_into(encoder: ImageEncoder, path: &Path) -> EncoderLoadError {
    let err = encoder.load_torchvision(path).unwrap_err();
    eprintln!("{err}");
    assert_eq!(named_file(&err), path, "{err:?}");
    assert!(err.to_string().contains(&*path.to_string_lossy()), "{err}");
    err
}

/// The error of loading the fixture `name` into the tiny encoder (see `load_error_into`).
fn load_error(name: &str) -> EncoderLoadError {
    load_error_into(tiny_encoder(&Device::ndarray()), &fixture(name))
}

#[test]
fn parameters_arrive_bit_for_bit() {
    let encoder = fixture_encoder(&Device::ndarray());
    let (shape, conv1) = npy("conv1_weight.npy");
    assert_eq!(shape, vec![8, 3, 7, 7]);
    assert_eq!(values(encoder.conv1.weight.val()), conv1, "conv1.weight");

    // BatchNorm weight -> gamma.
    let (_, bn1_weight) = npy("bn1_weight.npy");
    assert_eq!(values(encoder.bn1.gamma.val()), bn1_weight, "bn1.weight");

    // downsample.0 -> downsample.conv.
    let (shape, down) = npy("layer2_0_downsample_0_weight.npy");
    assert_eq!(shape, vec![16, 8, 1, 1]);
    let loaded = encoder.layer2[0]
        .downsample
        .as_ref()
        .unwrap()
        .conv
        .weight
        .val();
    assert_eq!(values(loaded), down, "layer2.0.downsample.0.weight");

    // Running statistics (a buffer, not a parameter, in torch).
    let (_, running_var) = npy("layer3_1_bn2_running_var.npy");
    let loaded = encoder.layer3[1].bn2.running_var.value();
    assert_eq!(values(loaded), running_var, "layer3.1.bn2.running_var");
}

#[test]
fn forward_matches_torch_in_eval_mode() {
    // The inference (non-autodiff) device: BatchNorm normalises with the running statistics.
    let device = Device::ndarray();
    let encoder = fixture_encoder(&device);
    let (in_shape, input) = npy("input.npy");
    assert_eq!(in_shape, vec![2, 3, 32, 32]);
    let (out_shape, expected) = npy("output.npy");
    assert_eq!(out_shape, vec![2, 64, 16, 16]);

    let images = Tensor::<4>::from_data(TensorData::new(input, [2, 3, 32, 32]), &device);
    let out = encoder.forward(images);
    assert_eq!(out.dims(), [2, 64, 16, 16]);
    let out = values(out);

    let (worst, diff) = out
        .iter()
        .zip(&expected)
        .map(|(a, b)| (a - b).abs())
        .enumerate()
        .fold((0, 0.0f32), |m, (i, d)| if d > m.1 { (i, d) } else { m });
    eprintln!("max |ours - torch| = {diff:e} at flat index {worst}");
    assert!(
        diff <= FORWARD_TOLERANCE,
        "max |ours - torch| = {diff} at flat index {worst} (ours {}, torch {})",
        out[worst],
        expected[worst]
    );
    // The comparison is not vacuous: the features are far from zero and from the init's.
    assert!(expected.iter().any(|&x| x > 1.0));
}

#[test]
fn truncated_file_is_a_read_error_naming_it() {
    let bytes = std::fs::read(fixture("resnet_tiny.pth")).unwrap();
    let dir = std::env::temp_dir().join(format!("nia-encoder-torchvision-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (tag, len) in [
        ("half", bytes.len() / 2),
        ("tail_cut", bytes.len() - 100),
        ("empty", 0),
    ] {
        let path = dir.join(format!("truncated_{tag}.pth"));
        std::fs::write(&path, &bytes[..len]).unwrap();
        let err = load_error_into(tiny_encoder(&Device::ndarray()), &path);
        assert!(
            matches!(&err, EncoderLoadError::Read { .. }),
            "{tag}: {err:?}"
        );
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn nonexistent_file_is_a_read_error_naming_it() {
    let err = load_error("does_not_exist.pth");
    assert!(matches!(&err, EncoderLoadError::Read { .. }), "{err:?}");
    assert!(err.to_string().contains("does_not_exist.pth"), "{err}");
}

#[test]
fn missing_layer3_is_reported_tensor_by_tensor() {
    let err = load_error("resnet_tiny_without_layer3.pth");
    let EncoderLoadError::MissingTensors { missing, .. } = &err else {
        panic!("expected MissingTensors, got {err:?}");
    };
    // Block 0: conv1, bn1 x4, conv2, bn2 x4, downsample conv + bn x4; block 1: 10.
    assert_eq!(missing.len(), 25, "{missing:?}");
    assert!(
        missing.iter().all(|k| k.starts_with("layer3.")),
        "{missing:?}"
    );
    for key in [
        "layer3.0.conv1.weight",
        "layer3.0.bn1.weight",
        "layer3.0.downsample.0.weight",
        "layer3.0.downsample.1.running_var",
        "layer3.1.bn2.bias",
    ] {
        assert!(missing.iter().any(|k| k == key), "{key} not in {missing:?}");
    }
    let message = err.to_string();
    assert!(
        message.contains("resnet_tiny_without_layer3.pth") && message.contains("layer3."),
        "{message}"
    );
}

#[test]
fn wrong_width_names_the_tensor_and_both_shapes() {
    let encoder = ImageEncoderConfig::new()
        .with_base_width(16)
        .init(&Device::ndarray());
    let err = load_error_into(encoder, &fixture("resnet_tiny.pth"));
    match &err {
        EncoderLoadError::ShapeMismatch {
            tensor,
            expected,
            found,
            base_width,
            others,
            ..
        } => {
            assert_eq!(tensor, "conv1.weight");
            assert_eq!(*expected, vec![16, 3, 7, 7]);
            assert_eq!(*found, vec![8, 3, 7, 7]);
            assert_eq!(*base_width, 16);
            // Every trunk tensor has the wrong width.
            assert!(*others > 50, "{others}");
        }
        other => panic!("expected ShapeMismatch, got {other:?}"),
    }
    let parts = [
        "resnet_tiny.pth",
        "conv1.weight",
        "[8, 3, 7, 7]",
        "[16, 3, 7, 7]",
    ];
    common::assert_mentions(&err.to_string(), &parts);
}

#[test]
fn resnet34_style_extra_block_is_refused() {
    let err = load_error("resnet_extra_block.pth");
    let EncoderLoadError::UnexpectedTensors { unexpected, .. } = &err else {
        panic!("expected UnexpectedTensors, got {err:?}");
    };
    assert_eq!(
        *unexpected,
        vec![
            "layer1.2.bn1.bias",
            "layer1.2.bn1.running_mean",
            "layer1.2.bn1.running_var",
            "layer1.2.bn1.weight",
            "layer1.2.conv1.weight",
        ]
    );
}

#[test]
fn float64_tensor_is_refused() {
    let err = load_error("resnet_f64_conv1.pth");
    let EncoderLoadError::UnsupportedDType { tensor, found, .. } = &err else {
        panic!("expected UnsupportedDType, got {err:?}");
    };
    assert_eq!(tensor, "conv1.weight");
    assert_eq!(*found, DType::F64);
}
