//! Broken SMPL body-model files.

use super::*;

/// A setup that edits the arrays of the dataset's body model with `edit`, then trains.
fn model_edit(
    edit: impl Fn(&mut Vec<(String, NdArray)>) + 'static,
) -> impl Fn(&mut Ctx) -> Vec<OsString> {
    move |c| {
        c.edit_npz("body_model.npz", &edit);
        c.train()
    }
}

pub(super) fn cases() -> Vec<Case> {
    let v = model_vertices();
    let list = pickle_write::to_pickle_bytes(&PyValue::List(vec![PyValue::Int(1)])).unwrap();
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
            model_edit(|a| a.retain(|(n, _)| n != "weights")),
        ),
        case(
            "smpl_wrong_vertex_count",
            &["body_model.npz", &format!("{}", v - 1)],
            model_edit(move |a| keep_rows(npz_array(a, "v_template"), v - 1)),
        ),
        case(
            "smpl_weights_not_normalised",
            &["body_model.npz", "weights", "summing to 1"],
            model_edit(|a| {
                let w = npz_array(a, "weights");
                let old = w.to_f64_vec().unwrap()[0];
                set_f(w, 0, old + 0.5);
            }),
        ),
        case(
            "smpl_face_index_out_of_range",
            &["body_model.npz", "`f`", "face 0"],
            model_edit(|a| match &mut npz_array(a, "f").data {
                ArrayData::U32(v) => v[2] = 99_999,
                ArrayData::I64(v) => v[2] = 99_999,
                ArrayData::I32(v) => v[2] = 99_999,
                other => panic!("faces {}", other.dtype_name()),
            }),
        ),
        case("smpl_pkl_not_a_pickle", &["bad_smpl.pkl", "pickle"], |c| {
            c.train_with_file("bad_smpl.pkl", b"this is not a pickle\n", "smpl_model")
        }),
        case(
            "smpl_pkl_of_a_list",
            &["list_smpl.pkl", "a dict with keys", "list"],
            move |c| c.train_with_file("list_smpl.pkl", &list, "smpl_model"),
        ),
        case(
            "smpl_unknown_extension",
            &["smpl.obj", "unknown extension", ".pkl"],
            |c| c.train_with_file("smpl.obj", b"v 0 0 0\n", "smpl_model"),
        ),
    ]
}
