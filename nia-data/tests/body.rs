//! Body model tests: validation, loading from SMPL-keyed dicts, SMPL's LBS against analytic
//! poses, the per-point reposing helpers, the procedural body and the motions.

use std::f32::consts::FRAC_PI_2;
use std::path::Path;
use std::sync::OnceLock;
use std::time::Instant;

use glam::{Mat3, Mat4, Vec3};
use nia_data::body::{
    blend_transform, inverse_lbs, pose_for_motion, rodrigues, signed_volume, BodyError, BodyModel,
    MeshTopology, MotionKind, ProceduralBody, ProceduralSpec, SmplParams, NUM_JOINTS,
    NUM_POSE_FEATURES, SMPL_PARENTS,
};
use nia_data::formats::{ArrayData, NdArray, PyValue};

/// Posed positions are products of f32 matrices built from f64 trigonometry; coordinates are
/// below 2 m, so f32 rounding stays under ~1e-6 m.
const POSE_TOL_M: f32 = 2e-6;

/// The brief's tolerance for the procedural regressor: designed joints within 1 mm.
const JOINT_TOL_M: f32 = 1e-3;

/// A 24-joint test model: vertex `k` sits on joint `k` (the regressor reads joint `k` from it,
/// weight 1) and is skinned to joint `k` alone; vertices 24..48 are offset copies, also
/// skinned to joint `k`; vertex 48 is split 30/70 between L_elbow and L_wrist.
fn chain_model() -> BodyModel {
    let joint = |k: usize| {
        Vec3::new(
            k as f32 * 0.07 - 0.8,
            (k % 5) as f32 * 0.11 - 0.2,
            (k % 3) as f32 * 0.05,
        )
    };
    let mut v_template: Vec<Vec3> = (0..NUM_JOINTS).map(joint).collect();
    v_template.extend((0..NUM_JOINTS).map(|k| joint(k) + Vec3::new(0.05, 0.02, -0.03)));
    v_template.push((joint(18) + joint(20)) * 0.5 + Vec3::Y * 0.02);
    let v = v_template.len();
    let mut weights = vec![[0.0f32; NUM_JOINTS]; v];
    for (i, w) in weights.iter_mut().enumerate().take(2 * NUM_JOINTS) {
        w[i % NUM_JOINTS] = 1.0;
    }
    weights[48][18] = 0.3;
    weights[48][20] = 0.7;
    let shapedirs = (0..v * 3 * 2)
        .map(|i| ((i * 37) % 11) as f32 * 1e-3 - 5e-3)
        .collect();
    BodyModel::new(
        v_template,
        shapedirs,
        vec![0.0; v * 3 * NUM_POSE_FEATURES],
        (0..NUM_JOINTS).map(|k| vec![(k as u32, 1.0)]).collect(),
        weights,
        SMPL_PARENTS.to_vec(),
        vec![[0, 1, 2], [24, 25, 26], [46, 47, 48]],
    )
    .expect("chain model is valid")
}

fn assert_close(a: Vec3, b: Vec3, tol: f32, what: &str) {
    assert!(a.distance(b) <= tol, "{what}: {a} vs {b}");
}

#[test]
fn zero_pose_and_shape_give_the_template_then_rh_th() {
    let model = chain_model();
    let posed = model.lbs(&SmplParams::default());
    for (p, t) in posed.vertices.iter().zip(&model.v_template) {
        assert_close(*p, *t, POSE_TOL_M, "rest vertex");
    }
    let rh = Vec3::new(0.3, -1.2, 0.5);
    let th = Vec3::new(1.0, 0.2, -3.0);
    let placed = model.lbs(&SmplParams {
        rh,
        th,
        ..SmplParams::default()
    });
    let r = rodrigues(rh);
    for (p, t) in placed.vertices.iter().zip(&model.v_template) {
        assert_close(*p, r * *t + th, POSE_TOL_M, "placed vertex");
    }
    for (j, t) in placed.joints.iter().zip(&model.v_template) {
        assert_close(*j, r * *t + th, POSE_TOL_M, "placed joint");
    }
}

#[test]
fn one_joint_rotated_90_degrees_about_z_moves_its_subtree_analytically() {
    let model = chain_model();
    let mut params = SmplParams::default();
    params.poses[3 * 18 + 2] = FRAC_PI_2; // L_elbow, 90 degrees about z
    let posed = model.lbs(&params);
    let pivot = model.v_template[18];
    let rot = |p: Vec3| {
        let d = p - pivot;
        pivot + Vec3::new(-d.y, d.x, d.z) // Rz(90): (x, y) -> (-y, x)
    };
    let subtree = [18, 20, 22]; // L_elbow, L_wrist, L_hand
    for (i, (&p, &t)) in posed.vertices.iter().zip(&model.v_template).enumerate() {
        let k = i % NUM_JOINTS;
        // Vertex 48 is split 30/70 between joints 18 and 20, which move the same way here.
        let expected = if i == 48 || subtree.contains(&k) {
            rot(t)
        } else {
            t
        };
        assert_close(p, expected, POSE_TOL_M, &format!("vertex {i}"));
    }
    for k in 0..NUM_JOINTS {
        let rest = model.v_template[k];
        let expected = if subtree.contains(&k) {
            rot(rest)
        } else {
            rest
        };
        assert_close(posed.joints[k], expected, POSE_TOL_M, &format!("joint {k}"));
    }
}

#[test]
fn chained_rotations_compose_along_the_tree() {
    let model = chain_model();
    let mut params = SmplParams::default();
    params.poses[3 * 16] = 0.7; // L_shoulder about x
    params.poses[3 * 18 + 1] = -0.4; // L_elbow about y
    let posed = model.lbs(&params);
    let j = |k: usize| model.v_template[k];
    let r16 = Mat3::from_rotation_x(0.7);
    let r18 = Mat3::from_rotation_y(-0.4);
    let elbow = j(16) + r16 * (j(18) - j(16));
    let wrist = elbow + r16 * r18 * (j(20) - j(18));
    assert_close(posed.joints[18], elbow, POSE_TOL_M, "elbow");
    assert_close(posed.joints[20], wrist, POSE_TOL_M, "wrist");
    assert_close(posed.vertices[20], wrist, POSE_TOL_M, "wrist vertex");
}

#[test]
fn global_rh_th_apply_after_skinning_as_in_zju() {
    let model = chain_model();
    let mut params = SmplParams::default();
    for (i, p) in params.poses.iter_mut().enumerate().skip(3) {
        *p = ((i * 13) % 7) as f32 * 0.08 - 0.24;
    }
    params.shapes = vec![0.5, -1.0];
    let local = model.lbs(&params);
    params.rh = Vec3::new(0.0, 2.5, 0.3);
    params.th = Vec3::new(0.4, -0.1, 2.0);
    let world = model.lbs(&params);
    let r = rodrigues(params.rh);
    for (w, l) in world.vertices.iter().zip(&local.vertices) {
        assert_close(*w, r * *l + params.th, POSE_TOL_M, "world vertex");
    }
    for (k, (w, l)) in world.joints.iter().zip(&local.joints).enumerate() {
        assert_close(
            *w,
            r * *l + params.th,
            POSE_TOL_M,
            &format!("world joint {k}"),
        );
    }
    // The joint transforms map shaped rest space to world space.
    for (v, (&p, w)) in world.v_shaped.iter().zip(&model.weights).enumerate() {
        let blended = blend_transform(w, &world.joint_transforms);
        assert_close(
            blended.transform_point3(p),
            world.vertices[v],
            POSE_TOL_M,
            "A_k",
        );
    }
}

#[test]
fn shape_blend_shapes_and_regressed_joints_follow_betas() {
    let model = chain_model();
    let betas = [0.8f32, -1.5];
    let posed = model.lbs(&SmplParams {
        shapes: betas.to_vec(),
        ..SmplParams::default()
    });
    let s = model.num_betas();
    assert_eq!(s, 2);
    for (v, shaped) in posed.v_shaped.iter().enumerate() {
        let mut expected = model.v_template[v];
        for c in 0..3 {
            for (b, beta) in betas.iter().enumerate() {
                expected[c] += model.shapedirs[(v * 3 + c) * s + b] * beta;
            }
        }
        assert_close(*shaped, expected, POSE_TOL_M, "v_shaped");
        assert_close(posed.vertices[v], expected, POSE_TOL_M, "rest pose vertex");
    }
    for k in 0..NUM_JOINTS {
        assert_close(posed.rest_joints[k], posed.v_shaped[k], POSE_TOL_M, "joint");
    }
    // Missing betas count as zero, extra ones are ignored.
    let short = model.lbs(&SmplParams {
        shapes: vec![0.8],
        ..SmplParams::default()
    });
    let long = model.lbs(&SmplParams {
        shapes: vec![0.8, 0.0, 5.0, 5.0],
        ..SmplParams::default()
    });
    assert_eq!(short.vertices, long.vertices);
}

#[test]
fn pose_blend_shapes_use_row_major_r_minus_identity() {
    let mut model = chain_model();
    // Vertex 30 sits on the root (identity transform); give it one pose corrective: its y
    // coordinate follows feature (joint 5, row 0, column 1) = R_5[0][1].
    let p = (5 - 1) * 9 + 1;
    model.posedirs[(30 * 3 + 1) * NUM_POSE_FEATURES + p] = 1.0;
    model.weights[30] = [0.0; NUM_JOINTS];
    model.weights[30][0] = 1.0;
    model.validate().unwrap();
    let theta = 0.6f32;
    let mut params = SmplParams::default();
    params.poses[3 * 5 + 2] = theta; // R_knee about z: R[0][1] = -sin(theta)
    let posed = model.lbs(&params);
    let expected = model.v_template[30] + Vec3::Y * -theta.sin();
    assert_close(posed.vertices[30], expected, POSE_TOL_M, "corrected vertex");
}

#[test]
fn inverse_lbs_recovers_the_rest_point() {
    let model = chain_model();
    let mut params = SmplParams::default();
    for (i, p) in params.poses.iter_mut().enumerate() {
        *p = ((i * 7) % 9) as f32 * 0.1 - 0.4;
    }
    params.rh = Vec3::new(0.2, 0.4, -0.1);
    params.th = Vec3::new(0.0, 1.0, 3.0);
    let posed = model.lbs(&params);
    for v in 0..model.num_vertices() {
        let back = inverse_lbs(
            posed.vertices[v],
            &model.weights[v],
            &posed.joint_transforms,
        )
        .expect("a rigid or mildly blended transform is invertible");
        // Inversion of an f32 blend of rotations: ~10x the forward rounding.
        assert_close(back, posed.v_shaped[v], 10.0 * POSE_TOL_M, "inverse LBS");
    }
}

#[test]
fn near_singular_blend_returns_none_without_nan() {
    let transforms = [
        Mat4::from_rotation_z(FRAC_PI_2),
        Mat4::from_rotation_z(-FRAC_PI_2),
        Mat4::from_rotation_x(std::f32::consts::PI),
    ];
    // Rz(90) + Rz(-90) halves to diag(0, 0, 1): determinant 0.
    assert_eq!(
        inverse_lbs(Vec3::new(0.1, 0.2, 0.3), &[0.5, 0.5, 0.0], &transforms),
        None
    );
    // Identity-like blend against a half-turn: (I + Rx(180)) / 2 = diag(1, 0, 0).
    let with_identity = [Mat4::IDENTITY, transforms[2]];
    assert_eq!(inverse_lbs(Vec3::ONE, &[0.5, 0.5], &with_identity), None);
    // A 70/30 blend of the same pair is well conditioned and finite.
    let p = inverse_lbs(Vec3::ONE, &[0.7, 0.3], &with_identity).expect("invertible");
    assert!(p.is_finite());
    // NaN input stays out of the result.
    assert_eq!(
        inverse_lbs(Vec3::ONE, &[f32::NAN, 0.5], &with_identity),
        None
    );
}

#[test]
fn construction_errors_name_the_field_and_shape() {
    let m = chain_model();
    let rebuild = |edit: &dyn Fn(&mut BodyModel)| {
        let mut c = m.clone();
        edit(&mut c);
        BodyModel::new(
            c.v_template,
            c.shapedirs,
            c.posedirs,
            c.j_regressor,
            c.weights,
            c.parents,
            c.faces,
        )
        .unwrap_err()
        .to_string()
    };
    type Edit = Box<dyn Fn(&mut BodyModel)>;
    let cases: Vec<(Edit, &[&str])> = vec![
        (
            Box::new(|c| {
                c.weights.pop();
            }),
            &["weights", "[49, 24]", "[48, 24]"],
        ),
        (Box::new(|c| c.weights[3][0] = 0.5), &["weights", "row 3"]),
        (
            Box::new(|c| c.parents[3] = 5),
            &["kintree_table", "joint 3"],
        ),
        (
            Box::new(|c| c.parents[0] = 0),
            &["kintree_table", "joint 0"],
        ),
        (
            Box::new(|c| {
                c.parents.pop();
            }),
            &["kintree_table", "24"],
        ),
        (Box::new(|c| c.faces[1][2] = 49), &["`f`", "< V = 49"]),
        (
            Box::new(|c| c.v_template[2].y = f32::NAN),
            &["v_template", "finite"],
        ),
        (
            Box::new(|c| {
                c.posedirs.pop();
            }),
            &["posedirs", "[49, 3, 207]"],
        ),
        (
            Box::new(|c| {
                c.shapedirs.pop();
            }),
            &["shapedirs", "[V, 3, S]"],
        ),
        (
            Box::new(|c| c.j_regressor[4] = vec![(99, 1.0)]),
            &["J_regressor", "row 4"],
        ),
    ];
    for (edit, needles) in cases {
        let msg = rebuild(edit.as_ref());
        assert!(msg.contains("<in-memory body model>"), "{msg}");
        for n in needles {
            assert!(msg.contains(n), "{msg} should mention {n}");
        }
    }
}

fn set_key(dict: &mut PyValue, key: &str, value: PyValue) {
    if let PyValue::Dict(items) = dict {
        for (k, v) in items.iter_mut() {
            if k.as_str() == Some(key) {
                *v = value;
                return;
            }
        }
        items.push((PyValue::Str(key.into()), value));
    }
}

#[test]
fn from_dict_reads_smpl_conventions_and_names_file_and_key() {
    let model = chain_model();
    let mut dict = model.to_dict();
    // SMPL's own kintree_table is int64 with 4294967295 at the root.
    let mut kintree: Vec<i64> = SMPL_PARENTS.iter().map(|&p| p as i64).collect();
    kintree[0] = 4294967295;
    kintree.extend(0..NUM_JOINTS as i64);
    set_key(
        &mut dict,
        "kintree_table",
        PyValue::Array(NdArray::new(vec![2, NUM_JOINTS], ArrayData::I64(kintree))),
    );
    // Python 2 pickles key by bytes; unrelated keys are ignored.
    if let PyValue::Dict(items) = &mut dict {
        for (k, _) in items.iter_mut() {
            if let PyValue::Str(s) = k {
                *k = PyValue::Bytes(s.clone().into_bytes());
            }
        }
        items.push((PyValue::Str("bs_style".into()), PyValue::Str("lbs".into())));
    }
    let back = BodyModel::from_dict(&dict, Path::new("SMPL_NEUTRAL.pkl")).unwrap();
    assert_eq!(back, model);
    assert_eq!(back.parents[0], -1);

    let path = Path::new("/models/SMPL_NEUTRAL.pkl");
    let mut bad = model.to_dict();
    set_key(
        &mut bad,
        "f",
        PyValue::Array(NdArray::new(vec![1, 3], ArrayData::I64(vec![0, 1, 49]))),
    );
    let msg = BodyModel::from_dict(&bad, path).unwrap_err().to_string();
    assert!(
        msg.contains("/models/SMPL_NEUTRAL.pkl") && msg.contains("`f`"),
        "{msg}"
    );

    let mut bad = model.to_dict();
    set_key(&mut bad, "shapedirs", PyValue::Str("oops".into()));
    let msg = BodyModel::from_dict(&bad, path).unwrap_err().to_string();
    assert!(
        msg.contains("shapedirs") && msg.contains("numeric array"),
        "{msg}"
    );

    let mut bad = model.to_dict();
    if let PyValue::Dict(items) = &mut bad {
        items.retain(|(k, _)| k.as_str() != Some("J_regressor"));
    }
    let err = BodyModel::from_dict(&bad, path).unwrap_err();
    assert!(matches!(&err, BodyError::MissingKey { key, .. } if key == "J_regressor"));
    assert!(err.to_string().contains("/models/SMPL_NEUTRAL.pkl"));

    let msg = BodyModel::load(Path::new("/nonexistent/SMPL_NEUTRAL.pkl"))
        .unwrap_err()
        .to_string();
    assert!(msg.contains("/nonexistent/SMPL_NEUTRAL.pkl"), "{msg}");
}

/// A scratch file path unique to this test process.
fn scratch_path(name: &str) -> std::path::PathBuf {
    std::env::temp_dir().join(format!("nia_body_test_{}_{name}", std::process::id()))
}

/// `value` as a chumpy `Ch` object, as SMPL's pickles store most arrays.
fn chumpy(value: PyValue) -> PyValue {
    PyValue::Object {
        class: "chumpy.ch.Ch".into(),
        args: vec![],
        state: Box::new(PyValue::Dict(vec![(PyValue::Str("x".into()), value)])),
    }
}

#[test]
fn smpl_pickle_with_chumpy_and_scipy_values_loads() {
    let model = chain_model();
    let v = model.num_vertices();
    let mut dict = model.to_dict();
    // J_regressor as scipy's csc_matrix state: column-compressed rows of each vertex.
    let (mut data, mut indices, mut indptr) = (Vec::new(), Vec::new(), vec![0i32]);
    for col in 0..v as u32 {
        for (k, row) in model.j_regressor.iter().enumerate() {
            if let Some(&(_, w)) = row.iter().find(|(i, _)| *i == col) {
                data.push(w as f64);
                indices.push(k as i32);
            }
        }
        indptr.push(data.len() as i32);
    }
    let array = |shape: Vec<usize>, d: ArrayData| PyValue::Array(NdArray::new(shape, d));
    let nnz = data.len();
    let csc = PyValue::Object {
        class: "scipy.sparse._csc.csc_matrix".into(),
        args: vec![],
        state: Box::new(PyValue::Dict(vec![
            (
                PyValue::Str("_shape".into()),
                PyValue::Tuple(vec![PyValue::Int(24), PyValue::Int(v as i64)]),
            ),
            (PyValue::Str("maxprint".into()), PyValue::Int(50)),
            (
                PyValue::Str("indices".into()),
                array(vec![nnz], ArrayData::I32(indices)),
            ),
            (
                PyValue::Str("indptr".into()),
                array(vec![v + 1], ArrayData::I32(indptr)),
            ),
            (
                PyValue::Str("data".into()),
                array(vec![nnz], ArrayData::F64(data)),
            ),
        ])),
    };
    if let PyValue::Dict(items) = &mut dict {
        for (k, value) in items.iter_mut() {
            match k.as_str() {
                Some("J_regressor") => *value = csc.clone(),
                Some("v_template" | "shapedirs" | "posedirs" | "weights") => {
                    *value = chumpy(value.clone())
                }
                _ => {}
            }
        }
    }
    let bytes = nia_data::formats::pickle_write::to_pickle_bytes(&dict).unwrap();
    let path = scratch_path("SMPL_NEUTRAL.pkl");
    std::fs::write(&path, bytes).unwrap();
    let loaded = BodyModel::load(&path);
    std::fs::remove_file(&path).ok();
    assert_eq!(loaded.unwrap(), model);
}

#[test]
fn npz_written_from_to_arrays_loads_back() {
    let model = chain_model();
    let arrays = model.to_arrays();
    let named: Vec<(&str, &NdArray)> = arrays.iter().map(|(k, a)| (k.as_str(), a)).collect();
    let path = scratch_path("smpl.npz");
    nia_data::formats::npz::write(&path, &named).unwrap();
    let loaded = BodyModel::load(&path);
    std::fs::remove_file(&path).ok();
    assert_eq!(loaded.unwrap(), model);
}

/// The default procedural body, built once for all tests of this file.
fn procedural() -> &'static (ProceduralBody, BodyModel, f64) {
    static BODY: OnceLock<(ProceduralBody, BodyModel, f64)> = OnceLock::new();
    BODY.get_or_init(|| {
        let start = Instant::now();
        let design = ProceduralBody::new(&ProceduralSpec::default()).unwrap();
        let model = design.build().unwrap();
        (design, model, start.elapsed().as_secs_f64())
    })
}

#[test]
fn procedural_body_is_a_watertight_outward_sphere() {
    let (_, model, seconds) = procedural();
    eprintln!(
        "procedural body: {} vertices, {} faces in {seconds:.3} s",
        model.num_vertices(),
        model.faces.len()
    );
    assert!((5000..=7000).contains(&model.num_vertices()));
    let t = MeshTopology::analyse(&model.faces, model.num_vertices());
    assert!(t.is_closed_manifold(), "{t:?}");
    assert!(t.is_consistently_oriented(), "{t:?}");
    assert_eq!((t.euler_characteristic, t.components), (2, 1), "{t:?}");
    assert_eq!(t.used_vertices, model.num_vertices());
    // Outward faces give a positive volume; an adult is 0.05-0.09 m^3.
    let volume = signed_volume(&model.v_template, &model.faces);
    assert!((0.04..0.1).contains(&volume), "volume {volume}");
    // Every face is geometrically outward too: its normal agrees with the field's gradient.
    let (design, _, _) = procedural();
    let flipped = model
        .faces
        .iter()
        .filter(|f| {
            let [a, b, c] = f.map(|i| model.v_template[i as usize]);
            let n = (b - a).cross(c - a);
            n.dot(design.implicit.gradient((a + b + c) / 3.0)) <= 0.0
        })
        .count();
    assert_eq!(flipped, 0);
    let (lo, hi) = model
        .v_template
        .iter()
        .fold((Vec3::MAX, Vec3::MIN), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        });
    assert!((hi.y - lo.y - 1.70).abs() < 0.02, "height {}", hi.y - lo.y);
}

#[test]
fn procedural_regressor_reproduces_the_designed_joints() {
    let (design, model, _) = procedural();
    let joints = model.regress_joints(&model.v_template);
    for (k, (j, d)) in joints.iter().zip(&design.joints).enumerate() {
        assert_close(*j, *d, JOINT_TOL_M, &format!("joint {k}"));
    }
    assert!(model.j_regressor.iter().flatten().all(|&(_, w)| w > 0.0));
    // Skinning: each vertex mostly follows a joint whose bone is near it, e.g. the hands.
    let left_hand = model
        .v_template
        .iter()
        .position(|p| p.x > 0.82)
        .expect("a vertex at the left finger tips");
    assert!(model.weights[left_hand][22] + model.weights[left_hand][20] > 0.9);
}

#[test]
fn procedural_betas_change_proportions() {
    let (_, model, _) = procedural();
    let shaped = |s: usize, beta: f32| {
        let mut b = vec![0.0; model.num_betas()];
        b[s] = beta;
        let v = model.shape_vertices(&b);
        let j = model.regress_joints(&v);
        (v, j)
    };
    assert_eq!(model.num_betas(), 10);
    let extent = |v: &[Vec3]| {
        let (lo, hi) = v.iter().fold((Vec3::MAX, Vec3::MIN), |(lo, hi), p| {
            (lo.min(*p), hi.max(*p))
        });
        hi - lo
    };
    let rest = extent(&model.v_template);
    let rest_joints = model.regress_joints(&model.v_template);
    // Every component moves some vertex by at least 1.5 cm at beta = 1.
    for s in 0..10 {
        let (v, _) = shaped(s, 1.0);
        let moved = v
            .iter()
            .zip(&model.v_template)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0f32, f32::max);
        assert!(moved > 0.015, "component {s} moves at most {moved} m");
    }
    let (tall, _) = shaped(0, 2.0);
    let (short, _) = shaped(0, -2.0);
    assert!(extent(&tall).y > rest.y + 0.1 && extent(&short).y < rest.y - 0.1);
    let (_, legs) = shaped(2, 2.0);
    assert!(legs[7].y < rest_joints[7].y - 0.04, "ankle {}", legs[7].y);
    let (_, arms) = shaped(3, 2.0);
    assert!(
        arms[20].x > rest_joints[20].x + 0.05,
        "wrist {}",
        arms[20].x
    );
    let (_, shoulders) = shaped(4, 2.0);
    assert!(shoulders[16].x > rest_joints[16].x + 0.01);
    // Girth: the waist (template vertices 5-15 cm below spine1's height) widens ~20%.
    let waist: Vec<usize> = (0..model.num_vertices())
        .filter(|&i| (-0.25..-0.15).contains(&model.v_template[i].y))
        .collect();
    let width = |v: &[Vec3]| extent(&waist.iter().map(|&i| v[i]).collect::<Vec<_>>()).x;
    let (wide, _) = shaped(1, 2.0);
    assert!(
        width(&wide) > 1.15 * width(&model.v_template),
        "waist {} -> {}",
        width(&model.v_template),
        width(&wide)
    );
    let (big_head, _) = shaped(7, 2.0);
    assert!(extent(&big_head).y > rest.y + 0.02);
}

/// A coarse body, quick to generate.
fn coarse_spec() -> ProceduralSpec {
    ProceduralSpec {
        grid_step_m: 0.02,
        target_vertices: 2500,
        relax_iterations: 1,
        ..ProceduralSpec::default()
    }
}

#[test]
fn procedural_generation_is_deterministic_and_checks_its_spec() {
    let spec = coarse_spec();
    let a = ProceduralBody::generate(&spec).unwrap();
    let b = ProceduralBody::generate(&spec).unwrap();
    assert_eq!(a, b);
    let t = MeshTopology::analyse(&a.faces, a.num_vertices());
    assert!(
        t.is_closed_manifold() && t.is_consistently_oriented(),
        "{t:?}"
    );
    assert_eq!(t.euler_characteristic, 2);

    // The spec with one value out of range, and the field the error names.
    let with = |edit: fn(&mut ProceduralSpec)| {
        let mut bad = spec.clone();
        edit(&mut bad);
        bad
    };
    for (bad, field) in [
        (with(|s| s.height_m = -1.0), "height_m"),
        (with(|s| s.girth = f32::NAN), "girth"),
        (with(|s| s.grid_step_m = 0.0), "grid_step_m"),
        (with(|s| s.grid_step_m = 0.1), "grid_step_m"),
        (with(|s| s.target_vertices = 3), "target_vertices"),
    ] {
        let msg = ProceduralBody::generate(&bad).unwrap_err().to_string();
        assert!(msg.contains(field), "{msg}");
    }
}

#[test]
fn procedural_body_walks_without_tearing() {
    let (_, model, _) = procedural();
    let kind = MotionKind::Walk;
    let pose = |t: f32| SmplParams {
        poses: pose_for_motion(t, kind),
        shapes: vec![0.5, -0.5, 1.0],
        rh: Vec3::new(0.0, 0.3, 0.0),
        th: Vec3::new(0.1, 0.9, 2.0),
    };
    let a = model.lbs(&pose(0.25 * kind.period_s()));
    let b = model.lbs(&pose(0.75 * kind.period_s()));
    assert!(a.vertices.iter().chain(&b.vertices).all(|p| p.is_finite()));
    // Left ankle in front (+z turned by Rh) in one half of the cycle, behind in the other.
    let forward = rodrigues(Vec3::new(0.0, 0.3, 0.0)) * Vec3::Z;
    let ahead = |p: &nia_data::body::Posed| (p.joints[7] - p.joints[8]).dot(forward);
    assert!(
        ahead(&a) > 0.15 && ahead(&b) < -0.15,
        "{} {}",
        ahead(&a),
        ahead(&b)
    );
    // Skinning keeps edges from stretching wildly (no vertex torn off its neighbours).
    let worst = model
        .faces
        .iter()
        .flat_map(|f| [(f[0], f[1]), (f[1], f[2]), (f[2], f[0])])
        .map(|(i, j)| {
            let rest = model.v_template[i as usize].distance(model.v_template[j as usize]);
            let posed = a.vertices[i as usize].distance(a.vertices[j as usize]);
            posed / rest.max(1e-4)
        })
        .fold(0.0f32, f32::max);
    assert!(worst < 3.0, "an edge stretched {worst}x");
}

#[test]
fn motions_are_periodic_finite_and_root_free() {
    for kind in [MotionKind::Walk, MotionKind::ArmSwing, MotionKind::Idle] {
        for i in 0..20 {
            let t = i as f32 * 0.13;
            let p = pose_for_motion(t, kind);
            assert!(p.iter().all(|x| x.is_finite()));
            assert_eq!(&p[..3], &[0.0, 0.0, 0.0]);
            let q = pose_for_motion(t + kind.period_s(), kind);
            for (a, b) in p.iter().zip(&q) {
                assert!((a - b).abs() < 1e-3, "{kind:?} not periodic at {t}");
            }
        }
    }
    let walk = |t: f32| pose_for_motion(t * MotionKind::Walk.period_s(), MotionKind::Walk);
    // Legs alternate: left hip flexed (negative about x) a quarter cycle in, right hip then.
    assert!(walk(0.25)[3] < -0.3 && walk(0.25)[6] > 0.3);
    assert!(walk(0.75)[3] > 0.3 && walk(0.75)[6] < -0.3);
    let swing = |t: f32| pose_for_motion(t * ARM_SWING, MotionKind::ArmSwing);
    const ARM_SWING: f32 = nia_data::body::motion::ARM_SWING_PERIOD_S;
    assert!(swing(0.0)[3 * 16 + 2] < -1.0 && swing(0.5)[3 * 16 + 2] > 0.3);
}
