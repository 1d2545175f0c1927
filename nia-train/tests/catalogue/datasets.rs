//! Broken dataset folders: annotations, images, masks, vertices, parameters.

use super::*;

/// A decoded pickled dict.
type Dict = Vec<(PyValue, PyValue)>;

/// Removed from the training subject's folder: (case name, texts stderr must contain, path).
#[rustfmt::skip]
const REMOVED: &[(&str, &[&str], &str)] = &[
    ("annots_missing", &["CoreView_1/annots.npy", "missing", "cameras and image list"], "annots.npy"),
    ("camera_folder_missing", &["CoreView_1/Camera_B2", "camera folder missing"], "Camera_B2"),
    ("image_missing_for_a_frame", &["CoreView_1/Camera_B2/000001.jpg", "image missing for frame 1"],
        "Camera_B2/000001.jpg"),
    ("mask_folder_missing", &["CoreView_1/mask", "a mask folder"], "mask"),
    ("params_folder_missing", &["CoreView_1/params", "SMPL parameters folder"], "params"),
    ("vertices_folder_missing", &["CoreView_1/vertices", "SMPL vertices folder"], "vertices"),
];

/// Emptied folders of the training subject: (case name, texts stderr must contain, folder,
/// the ending of the files removed).
#[rustfmt::skip]
const EMPTIED: &[(&str, &[&str], &str, &str)] = &[
    ("mask_files_missing", &["CoreView_1/Camera_B", "no mask for this image", "mask/Camera_B"], "mask", ".png"),
    ("params_file_missing", &["CoreView_1/params/", ".npy", "missing", "SMPL parameters"], "params", ".npy"),
    ("vertices_file_missing", &["CoreView_1/vertices/", ".npy", "missing", "SMPL vertices"], "vertices", ".npy"),
];

/// A setup that applies `edit` to every file of the training subject's `folder` whose name
/// ends with `suffix`, then trains.
fn each_file(
    folder: &'static str,
    suffix: &'static str,
    edit: impl Fn(&mut Ctx, &str) + 'static,
) -> impl Fn(&mut Ctx) -> Vec<OsString> {
    move |c| {
        for f in c.files(&format!("{SUBJECT}/{folder}"), suffix) {
            edit(c, &f);
        }
        c.train()
    }
}

/// A setup that edits the training subject's `annots.npy` (a pickled dict), then trains.
fn annots_edit(edit: impl Fn(&mut Dict) + 'static) -> impl Fn(&mut Ctx) -> Vec<OsString> {
    move |c| {
        c.edit_object(&format!("{SUBJECT}/annots.npy"), &edit);
        c.train()
    }
}

/// A setup that edits every SMPL parameters file (a pickled dict) of the training subject.
fn params_edit(edit: impl Fn(&mut Dict) + 'static) -> impl Fn(&mut Ctx) -> Vec<OsString> {
    each_file("params", ".npy", move |c, f| c.edit_object(f, &edit))
}

/// A setup that replaces every vertices array of the training subject by `edit` of it.
fn vertices_edit(
    edit: impl Fn(NdArray) -> NdArray + 'static,
) -> impl Fn(&mut Ctx) -> Vec<OsString> {
    each_file("vertices", ".npy", move |c, f| {
        let p = c.at(f);
        let a = edit(npy::read(&p).unwrap());
        std::fs::remove_file(&p).unwrap();
        npy::write_array(&p, &a).unwrap();
    })
}

/// Whether `k` is the string `key`.
fn is_key(k: &PyValue, key: &str) -> bool {
    matches!(k, PyValue::Str(s) if s == key)
}

/// An edit that removes the entry `key` of a dict.
fn without(key: &'static str) -> impl Fn(&mut Dict) {
    move |items| items.retain(|(k, _)| !is_key(k, key))
}

pub(super) fn cases() -> Vec<Case> {
    let v = model_vertices();
    let mut cases: Vec<Case> = REMOVED
        .iter()
        .map(|&(name, expect, rel)| {
            case(name, expect, move |c| {
                c.remove(&format!("{SUBJECT}/{rel}"));
                c.train()
            })
        })
        .collect();
    cases.extend(EMPTIED.iter().map(|&(name, expect, folder, suffix)| {
        case(name, expect, each_file(folder, suffix, |c, f| c.remove(f)))
    }));
    cases.extend([
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
            annots_edit(without("ims")),
        ),
        case(
            "annots_missing_camera_T",
            &["CoreView_1/annots.npy", "T"],
            annots_edit(|items| {
                for (k, v) in items.iter_mut() {
                    if let (true, PyValue::Dict(cams)) = (is_key(k, "cams"), v) {
                        cams.retain(|(k, _)| !is_key(k, "T"));
                    }
                }
            }),
        ),
        case(
            "annots_too_few_image_paths",
            &["CoreView_1/annots.npy", "ims[0]['ims']", "4 image paths"],
            annots_edit(|items| {
                for (k, v) in items.iter_mut() {
                    if let (true, PyValue::List(frames)) = (is_key(k, "ims"), v) {
                        if let PyValue::Dict(f0) = &mut frames[0] {
                            if let PyValue::List(paths) = &mut f0[0].1 {
                                paths.pop();
                            }
                        }
                    }
                }
            }),
        ),
        case(
            "annots_nan_in_camera_K",
            &["CoreView_1/annots.npy", "K", "non-finite"],
            annots_edit(|items| {
                let cams = items
                    .iter_mut()
                    .find_map(|(k, v)| match (k, v) {
                        (PyValue::Str(s), PyValue::Dict(d)) if s == "cams" => Some(d),
                        _ => None,
                    })
                    .expect("cams");
                match cams.iter_mut().find(|(k, _)| is_key(k, "K")) {
                    Some((_, PyValue::List(ks))) => match &mut ks[0] {
                        PyValue::Array(a) => set_f(a, 0, f64::NAN),
                        other => panic!("K[0] is {}", other.type_name()),
                    },
                    Some((_, PyValue::Array(a))) => set_f(a, 0, f64::NAN),
                    _ => panic!("no cams['K']"),
                }
            }),
        ),
        case("subject_folder_missing", &["CoreView_1", "missing"], |c| {
            c.remove(SUBJECT);
            c.train()
        }),
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
            "params_with_nan",
            &["CoreView_1/params/", "poses", "non-finite", "NaN"],
            params_edit(|items| set_f(dict_array(items, "poses"), 5, f64::NAN)),
        ),
        case(
            "params_missing_key_Th",
            &["CoreView_1/params/", "Th", "no such key"],
            params_edit(without("Th")),
        ),
        case(
            "params_poses_wrong_length",
            &["CoreView_1/params/", "poses", "shape [1, 72]", "[1, 69]"],
            params_edit(|items| {
                let a = dict_array(items, "poses");
                a.shape = vec![1, 69];
                a.data = match &a.data {
                    ArrayData::F32(v) => ArrayData::F32(v[..69].to_vec()),
                    ArrayData::F64(v) => ArrayData::F64(v[..69].to_vec()),
                    _ => panic!("poses not float"),
                };
            }),
        ),
        case(
            "vertices_wrong_shape",
            &["CoreView_1/vertices/", "shape [V, 3]", &format!("[{v}, 2]")],
            vertices_edit(|a| {
                let xy: Vec<f32> = a
                    .to_f32_vec()
                    .unwrap()
                    .chunks_exact(3)
                    .flat_map(|v| [v[0], v[1]])
                    .collect();
                NdArray::new(vec![xy.len() / 2, 2], ArrayData::F32(xy))
            }),
        ),
        case(
            "vertices_with_nan",
            &["CoreView_1/vertices/", "non-finite"],
            vertices_edit(|mut a| {
                set_f(&mut a, 10, f64::NAN);
                a
            }),
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
            vertices_edit(move |mut a| {
                keep_rows(&mut a, v - 100);
                a
            }),
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
            vertices_edit(move |a| {
                let mut xyz = a.to_f32_vec().unwrap();
                let first: Vec<f32> = xyz[..300].to_vec();
                xyz.extend(first);
                NdArray::new(vec![v + 100, 3], ArrayData::F32(xyz))
            }),
        ),
        case(
            "monocap_format_without_lbs_folder",
            &["CoreView_1/lbs"],
            |c| {
                let config = c.config(&[("ratio = 1.0", "ratio = 1.0\nformat = \"monocap\"")]);
                c.train_args(&config, &[])
            },
        ),
    ]);
    cases
}
