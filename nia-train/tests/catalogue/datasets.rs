//! Broken dataset folders: annotations, images, masks, vertices, parameters.

use super::*;

pub(super) fn cases() -> Vec<Case> {
    let v = model_vertices();
    vec![
        case(
            "annots_missing",
            &["CoreView_1/annots.npy", "missing", "cameras and image list"],
            |c| {
                c.remove(&format!("{SUBJECT}/annots.npy"));
                c.train()
            },
        ),
        case(
            "annots_truncated",
            &["CoreView_1/annots.npy", "truncated"],
            |c| {
                let rel = format!("{SUBJECT}/annots.npy");
                let old = std::fs::read(c.at(&rel)).unwrap();
                c.write(&rel, &old[..old.len() / 2]);
                c.train()
            },
        ),
        case("annots_not_npy", &["CoreView_1/annots.npy"], |c| {
            c.write(&format!("{SUBJECT}/annots.npy"), b"this is not numpy\n");
            c.train()
        }),
        case(
            "annots_missing_key_ims",
            &["CoreView_1/annots.npy", "ims", "no such key"],
            |c| {
                c.edit_object(&format!("{SUBJECT}/annots.npy"), |items| {
                    items.retain(|(k, _)| !matches!(k, PyValue::Str(s) if s == "ims"))
                });
                c.train()
            },
        ),
        case(
            "annots_missing_camera_T",
            &["CoreView_1/annots.npy", "T"],
            |c| {
                c.edit_object(&format!("{SUBJECT}/annots.npy"), |items| {
                    for (k, v) in items.iter_mut() {
                        if matches!(k, PyValue::Str(s) if s == "cams") {
                            if let PyValue::Dict(cams) = v {
                                cams.retain(|(k, _)| !matches!(k, PyValue::Str(s) if s == "T"));
                            }
                        }
                    }
                });
                c.train()
            },
        ),
        case(
            "annots_too_few_image_paths",
            &["CoreView_1/annots.npy", "ims[0]['ims']", "4 image paths"],
            |c| {
                c.edit_object(&format!("{SUBJECT}/annots.npy"), |items| {
                    for (k, v) in items.iter_mut() {
                        if matches!(k, PyValue::Str(s) if s == "ims") {
                            if let PyValue::List(frames) = v {
                                if let PyValue::Dict(f0) = &mut frames[0] {
                                    if let PyValue::List(paths) = &mut f0[0].1 {
                                        paths.pop();
                                    }
                                }
                            }
                        }
                    }
                });
                c.train()
            },
        ),
        case("subject_folder_missing", &["CoreView_1", "missing"], |c| {
            c.remove(SUBJECT);
            c.train()
        }),
        case(
            "camera_folder_missing",
            &["CoreView_1/Camera_B2", "camera folder missing"],
            |c| {
                c.remove(&format!("{SUBJECT}/Camera_B2"));
                c.train()
            },
        ),
        case(
            "image_missing_for_a_frame",
            &[
                "CoreView_1/Camera_B2/000001.jpg",
                "image missing for frame 1",
            ],
            |c| {
                c.remove(&format!("{SUBJECT}/Camera_B2/000001.jpg"));
                c.train()
            },
        ),
        case(
            "jpeg_garbage",
            &["CoreView_1/Camera_B2/000000.jpg", "cannot decode image"],
            |c| {
                c.write(
                    &format!("{SUBJECT}/Camera_B2/000000.jpg"),
                    b"not a jpeg at all",
                );
                c.train()
            },
        ),
        // A half-downloaded JPEG: the decoder would fill the missing scan data in silently; the
        // reader refuses a JPEG without its end-of-image marker.
        case(
            "jpeg_truncated_tail",
            &["CoreView_1/Camera_B", ".jpg", "cannot decode image"],
            |c| {
                c.each(SUBJECT, ".jpg", |b| b[..b.len() * 3 / 4].to_vec());
                c.train()
            },
        ),
        case(
            "image_of_the_wrong_size",
            &[
                "CoreView_1/Camera_B",
                "000001.jpg",
                "16x16",
                "expected 32x32",
            ],
            |c| {
                let small = png(16, 16);
                for cam in 1..=4 {
                    c.write(&format!("{SUBJECT}/Camera_B{cam}/000001.jpg"), &small);
                }
                let config = c.config(&[]);
                c.train_args(&config, &["--steps", "4"])
            },
        ),
        case(
            "mask_folder_missing",
            &["CoreView_1/mask", "a mask folder"],
            |c| {
                c.remove(&format!("{SUBJECT}/mask"));
                c.train()
            },
        ),
        case(
            "mask_files_missing",
            &[
                "CoreView_1/Camera_B",
                "no mask for this image",
                "mask/Camera_B",
            ],
            |c| {
                for f in c.files(&format!("{SUBJECT}/mask"), ".png") {
                    c.remove(&f);
                }
                c.train()
            },
        ),
        case(
            "mask_of_the_wrong_size",
            &["CoreView_1/mask/Camera_B", ".png", "16x16", "32x32"],
            |c| {
                let small = png(16, 16);
                c.each(&format!("{SUBJECT}/mask"), ".png", |_| small.clone());
                c.train()
            },
        ),
        case(
            "mask_corrupt",
            &["CoreView_1/mask/Camera_B", ".png", "cannot decode image"],
            |c| {
                c.each(&format!("{SUBJECT}/mask"), ".png", |_| {
                    b"\x89PNG\r\n\x1a\nbroken".to_vec()
                });
                c.train()
            },
        ),
        case(
            "params_folder_missing",
            &["CoreView_1/params", "SMPL parameters folder"],
            |c| {
                c.remove(&format!("{SUBJECT}/params"));
                c.train()
            },
        ),
        case(
            "params_file_missing",
            &["CoreView_1/params/", ".npy", "missing", "SMPL parameters"],
            |c| {
                for f in c.files(&format!("{SUBJECT}/params"), ".npy") {
                    c.remove(&f);
                }
                c.train()
            },
        ),
        case(
            "params_with_nan",
            &["CoreView_1/params/", "poses", "non-finite", "NaN"],
            |c| {
                for f in c.files(&format!("{SUBJECT}/params"), ".npy") {
                    c.edit_object(&f, |items| set_f(dict_array(items, "poses"), 5, f64::NAN));
                }
                c.train()
            },
        ),
        case(
            "params_missing_key_Th",
            &["CoreView_1/params/", "Th", "no such key"],
            |c| {
                for f in c.files(&format!("{SUBJECT}/params"), ".npy") {
                    c.edit_object(&f, |items| {
                        items.retain(|(k, _)| !matches!(k, PyValue::Str(s) if s == "Th"))
                    });
                }
                c.train()
            },
        ),
        case(
            "params_poses_wrong_length",
            &["CoreView_1/params/", "poses", "shape [1, 72]", "[1, 69]"],
            |c| {
                for f in c.files(&format!("{SUBJECT}/params"), ".npy") {
                    c.edit_object(&f, |items| {
                        let a = dict_array(items, "poses");
                        a.shape = vec![1, 69];
                        a.data = match &a.data {
                            ArrayData::F32(v) => ArrayData::F32(v[..69].to_vec()),
                            ArrayData::F64(v) => ArrayData::F64(v[..69].to_vec()),
                            _ => panic!("poses not float"),
                        };
                    });
                }
                c.train()
            },
        ),
        case(
            "vertices_folder_missing",
            &["CoreView_1/vertices", "SMPL vertices folder"],
            |c| {
                c.remove(&format!("{SUBJECT}/vertices"));
                c.train()
            },
        ),
        case(
            "vertices_file_missing",
            &["CoreView_1/vertices/", ".npy", "missing", "SMPL vertices"],
            |c| {
                for f in c.files(&format!("{SUBJECT}/vertices"), ".npy") {
                    c.remove(&f);
                }
                c.train()
            },
        ),
        case(
            "vertices_wrong_shape",
            &["CoreView_1/vertices/", "shape [V, 3]", &format!("[{v}, 2]")],
            |c| {
                for f in c.files(&format!("{SUBJECT}/vertices"), ".npy") {
                    let p = c.at(&f);
                    let a = npy::read(&p).unwrap();
                    let xy: Vec<f32> = a
                        .to_f32_vec()
                        .unwrap()
                        .chunks_exact(3)
                        .flat_map(|v| [v[0], v[1]])
                        .collect();
                    std::fs::remove_file(&p).unwrap();
                    let n = xy.len() / 2;
                    npy::write_array(&p, &NdArray::new(vec![n, 2], ArrayData::F32(xy))).unwrap();
                }
                c.train()
            },
        ),
        case(
            "vertices_with_nan",
            &["CoreView_1/vertices/", "non-finite"],
            |c| {
                for f in c.files(&format!("{SUBJECT}/vertices"), ".npy") {
                    let p = c.at(&f);
                    let mut a = npy::read(&p).unwrap();
                    set_f(&mut a, 10, f64::NAN);
                    std::fs::remove_file(&p).unwrap();
                    npy::write_array(&p, &a).unwrap();
                }
                c.train()
            },
        ),
        // Stored vertices that do not fit the SMPL model: named with both files at open time.
        case(
            "vertices_fewer_than_the_smpl_model",
            &[
                "CoreView_1/vertices/",
                "body_model.npz",
                &format!("{}", v - 100),
                &format!("{v}"),
            ],
            move |c| {
                for f in c.files(&format!("{SUBJECT}/vertices"), ".npy") {
                    let p = c.at(&f);
                    let mut a = npy::read(&p).unwrap();
                    keep_rows(&mut a, v - 100);
                    std::fs::remove_file(&p).unwrap();
                    npy::write_array(&p, &a).unwrap();
                }
                c.train()
            },
        ),
        // More stored vertices than the model has.
        case(
            "vertices_more_than_the_smpl_model",
            &[
                "CoreView_1/vertices/",
                "body_model.npz",
                &format!("{}", v + 100),
                &format!("{v}"),
            ],
            move |c| {
                for f in c.files(&format!("{SUBJECT}/vertices"), ".npy") {
                    let p = c.at(&f);
                    let a = npy::read(&p).unwrap();
                    let mut xyz = a.to_f32_vec().unwrap();
                    let first: Vec<f32> = xyz[..300].to_vec();
                    xyz.extend(first);
                    std::fs::remove_file(&p).unwrap();
                    npy::write_array(&p, &NdArray::new(vec![v + 100, 3], ArrayData::F32(xyz)))
                        .unwrap();
                }
                c.train()
            },
        ),
        case(
            "annots_nan_in_camera_K",
            &["CoreView_1/annots.npy", "K", "non-finite"],
            |c| {
                c.edit_object(&format!("{SUBJECT}/annots.npy"), |items| {
                    let cams = items
                        .iter_mut()
                        .find_map(|(k, v)| match (k, v) {
                            (PyValue::Str(s), PyValue::Dict(d)) if s == "cams" => Some(d),
                            _ => None,
                        })
                        .expect("cams");
                    match cams
                        .iter_mut()
                        .find(|(k, _)| matches!(k, PyValue::Str(s) if s == "K"))
                    {
                        Some((_, PyValue::List(ks))) => match &mut ks[0] {
                            PyValue::Array(a) => set_f(a, 0, f64::NAN),
                            other => panic!("K[0] is {}", other.type_name()),
                        },
                        Some((_, PyValue::Array(a))) => set_f(a, 0, f64::NAN),
                        _ => panic!("no cams['K']"),
                    }
                });
                c.train()
            },
        ),
        case(
            "monocap_format_without_lbs_folder",
            &["CoreView_1/lbs"],
            |c| {
                let config = c.config(&[("ratio = 1.0", "ratio = 1.0\nformat = \"monocap\"")]);
                c.train_args(&config, &[])
            },
        ),
    ]
}
