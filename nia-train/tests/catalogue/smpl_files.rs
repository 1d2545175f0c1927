//! Broken SMPL body-model files.

use super::*;

pub(super) fn cases() -> Vec<Case> {
    let v = model_vertices();
    vec![
        case(
            "smpl_missing",
            &["body_model.npz", "cannot read", "No such file"],
            |c| {
                c.remove("body_model.npz");
                c.train()
            },
        ),
        case("smpl_npz_truncated", &["body_model.npz", "zip"], |c| {
            let old = std::fs::read(c.at("body_model.npz")).unwrap();
            c.write("body_model.npz", &old[..old.len() / 2]);
            c.train()
        }),
        case(
            "smpl_missing_weights",
            &["body_model.npz", "weights", "missing"],
            |c| {
                c.edit_npz("body_model.npz", |a| a.retain(|(n, _)| n != "weights"));
                c.train()
            },
        ),
        case(
            "smpl_wrong_vertex_count",
            &["body_model.npz", &format!("{}", v - 1)],
            move |c| {
                c.edit_npz("body_model.npz", |a| {
                    keep_rows(npz_array(a, "v_template"), v - 1)
                });
                c.train()
            },
        ),
        case(
            "smpl_weights_not_normalised",
            &["body_model.npz", "weights", "summing to 1"],
            |c| {
                c.edit_npz("body_model.npz", |a| {
                    let w = npz_array(a, "weights");
                    let old = w.to_f64_vec().unwrap()[0];
                    set_f(w, 0, old + 0.5);
                });
                c.train()
            },
        ),
        case(
            "smpl_face_index_out_of_range",
            &["body_model.npz", "`f`", "face 0"],
            |c| {
                c.edit_npz("body_model.npz", |a| {
                    let f = npz_array(a, "f");
                    match &mut f.data {
                        ArrayData::U32(v) => v[2] = 99_999,
                        ArrayData::I64(v) => v[2] = 99_999,
                        ArrayData::I32(v) => v[2] = 99_999,
                        other => panic!("faces {}", other.dtype_name()),
                    }
                });
                c.train()
            },
        ),
        case("smpl_pkl_not_a_pickle", &["bad_smpl.pkl", "pickle"], |c| {
            let pkl = c.dir.join("bad_smpl.pkl");
            std::fs::write(&pkl, b"this is not a pickle\n").unwrap();
            let line = format!("ratio = 1.0\nsmpl_model = \"{}\"", slash(&pkl));
            let config = c.config(&[("ratio = 1.0", &line)]);
            c.train_args(&config, &[])
        }),
        case(
            "smpl_pkl_of_a_list",
            &["list_smpl.pkl", "a dict with keys", "list"],
            |c| {
                let pkl = c.dir.join("list_smpl.pkl");
                let bytes =
                    pickle_write::to_pickle_bytes(&PyValue::List(vec![PyValue::Int(1)])).unwrap();
                std::fs::write(&pkl, bytes).unwrap();
                let line = format!("ratio = 1.0\nsmpl_model = \"{}\"", slash(&pkl));
                let config = c.config(&[("ratio = 1.0", &line)]);
                c.train_args(&config, &[])
            },
        ),
        case(
            "smpl_unknown_extension",
            &["smpl.obj", "unknown extension", ".pkl"],
            |c| {
                let p = c.dir.join("smpl.obj");
                std::fs::write(&p, b"v 0 0 0\n").unwrap();
                let line = format!("ratio = 1.0\nsmpl_model = \"{}\"", slash(&p));
                let config = c.config(&[("ratio = 1.0", &line)]);
                c.train_args(&config, &[])
            },
        ),
    ]
}
