//! Golden test: `BodyModel::lbs` against a NumPy transcription of smplx's `lbs()` (with
//! `batch_rodrigues` and `batch_rigid_transform`) followed by ZJU-MoCap's `@ R(Rh)^T + Th`, on a
//! small model whose arrays are closed-form functions of their indices (so both sides build the
//! same model without a data file). The root joint is rotated too, and `posedirs` is dense.
//!
//! The golden values were printed by this script (NumPy 2.4):
//!
//! ```python
//! import numpy as np
//! V, J, S = 12, 24, 3
//! parents = np.array([-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21])
//! i = np.arange(V)[:, None, None]; c = np.arange(3)[None, :, None]
//! v_template = np.sin(0.7 * i[:, :, 0] + 1.3 * c[:, :, 0]) * 0.5
//! shapedirs = 0.01 * np.cos(0.3 * i + 0.5 * c + 0.9 * np.arange(S)[None, None, :])
//! posedirs = 0.001 * np.sin(0.11 * i + 0.7 * c + 0.013 * np.arange(207)[None, None, :])
//! J_regressor = np.zeros((J, V))
//! for k in range(J):
//!     J_regressor[k, k % V] += 0.6
//!     J_regressor[k, (5 * k + 3) % V] += 0.4
//! kk, ii = np.meshgrid(np.arange(J), np.arange(V))
//! weights = 1.0 / (1.0 + ((kk * 7 + ii * 5) % 24)) ** 2
//! weights /= weights.sum(1, keepdims=True)
//! jj, cc = np.meshgrid(np.arange(J), np.arange(3), indexing="ij")
//! pose = (0.4 * np.sin(1.7 * jj + 2.3 * cc)).reshape(-1)
//! betas = np.array([0.5, -1.2, 2.0])
//! Rh = np.array([0.3, -0.5, 0.8]); Th = np.array([0.1, 0.2, -0.3])
//!
//! def batch_rodrigues(rot_vecs):  # smplx.lbs.batch_rodrigues
//!     angle = np.linalg.norm(rot_vecs + 1e-8, axis=1, keepdims=True)
//!     rot_dir = rot_vecs / angle
//!     cos = np.cos(angle)[:, None]; sin = np.sin(angle)[:, None]
//!     rx, ry, rz = np.split(rot_dir, 3, axis=1)
//!     zeros = np.zeros_like(rx)
//!     K = np.concatenate([zeros, -rz, ry, rz, zeros, -rx, -ry, rx, zeros], axis=1).reshape(-1, 3, 3)
//!     return np.eye(3)[None] + sin * K + (1 - cos) * K @ K
//!
//! v_shaped = v_template + np.einsum("l,mkl->mk", betas, shapedirs)
//! Jr = J_regressor @ v_shaped
//! rot = batch_rodrigues(pose.reshape(-1, 3))
//! pose_feature = (rot[1:] - np.eye(3)).reshape(-1)
//! v_posed = v_shaped + (pose_feature @ posedirs.reshape(-1, 207).T).reshape(-1, 3)
//! rel = Jr.copy(); rel[1:] -= Jr[parents[1:]]
//! T = np.zeros((J, 4, 4)); T[:, :3, :3] = rot; T[:, :3, 3] = rel; T[:, 3, 3] = 1
//! chain = [T[0]]
//! for k in range(1, J):
//!     chain.append(chain[parents[k]] @ T[k])
//! G = np.stack(chain)
//! posed_joints = G[:, :3, 3]
//! A = G.copy(); A[:, :3, 3] -= np.einsum("kij,kj->ki", G[:, :3, :3], Jr)
//! Tv = np.einsum("vk,kij->vij", weights, A)
//! verts = np.einsum("vij,vj->vi", Tv[:, :3, :3], v_posed) + Tv[:, :3, 3]
//! R = batch_rodrigues(Rh[None])[0]
//! world_verts = verts @ R.T + Th
//! world_joints = posed_joints @ R.T + Th
//! np.set_printoptions(precision=9, suppress=True)
//! for name, a in [("GOLDEN_VERTICES", world_verts), ("GOLDEN_JOINTS", world_joints)]:
//!     print(f"const {name}: [[f64; 3]; {len(a)}] = [")
//!     for row in a:
//!         print("    [" + ", ".join(f"{x:.9}" for x in row) + "],")
//!     print("];")
//! ```

use glam::Vec3;
use nia_data::body::{BodyModel, SmplParams, NUM_JOINTS, NUM_POSE_FEATURES, SMPL_PARENTS};

/// The inputs are rounded to f32 (~6e-8 relative) and posed through f32 blends; outputs are
/// below 1.1 m, so the f32 result agrees with the f64 reference to a few 1e-7 m.
const GOLDEN_TOL_M: f32 = 2e-6;

const V: usize = 12;
const S: usize = 3;

const GOLDEN_VERTICES: [[f64; 3]; 12] = [
    [-0.189634064, 0.551784193, 0.0204076096],
    [-0.0710581081, 0.97326995, -0.492385266],
    [0.351450914, 0.807602607, -0.56269683],
    [0.540494156, 0.911206612, -0.900399024],
    [0.381814595, 0.365690441, -0.782953768],
    [0.285842623, 0.161835969, -0.175717201],
    [0.0694733856, -0.0266171964, 0.0151868375],
    [-0.284739375, 0.108947178, 0.104220105],
    [-0.31310285, -0.242209242, -0.111903445],
    [-0.355391072, 0.629114404, -0.159641136],
    [0.108155824, 0.827048319, -0.393300952],
    [0.236817666, 0.850356582, -0.764337073],
];
const GOLDEN_JOINTS: [[f64; 3]; 24] = [
    [0.0448685409, 0.47416216, -0.24407536],
    [-0.132876363, 0.513289088, -0.0461800707],
    [0.254869367, 0.697794596, -0.382370068],
    [0.178661209, 0.0867098096, -0.502625786],
    [0.424943187, 0.571561108, -0.603050076],
    [0.510874074, -0.150450449, -0.531710896],
    [-0.161131321, 0.259642036, -0.0313640179],
    [0.00502551115, 0.242782716, -0.170714415],
    [-0.339351675, -0.60165773, -0.286084434],
    [-0.266611606, 0.764521952, -0.264948788],
    [0.134083756, 0.421007624, -0.39486044],
    [-0.0544907897, 0.418423559, 0.0545602004],
    [0.0863793556, 0.776681914, -0.516376403],
    [-0.131814328, 0.764509668, -0.359755632],
    [0.180356496, 1.02479537, -0.723367347],
    [0.428131822, 0.560525624, -0.783490301],
    [0.549185195, 1.05041015, -0.641114911],
    [0.45443312, 0.379056176, -0.161883908],
    [0.546482447, 0.221027703, -0.416585653],
    [-0.162409978, 0.488271379, -0.223550285],
    [0.312821831, 0.0839677312, -0.262733611],
    [-0.48907326, 0.793089773, -0.324974621],
    [0.258970863, 0.822451202, -0.455895783],
    [0.077986011, 0.857699172, -0.708769535],
];

/// The model of the script above, entry for entry.
fn golden_model() -> BodyModel {
    let v_template = (0..V)
        .map(|i| {
            let c = |c: usize| ((0.7 * i as f64 + 1.3 * c as f64).sin() * 0.5) as f32;
            Vec3::new(c(0), c(1), c(2))
        })
        .collect();
    let mut shapedirs = Vec::with_capacity(V * 3 * S);
    let mut posedirs = Vec::with_capacity(V * 3 * NUM_POSE_FEATURES);
    for i in 0..V {
        for c in 0..3 {
            for s in 0..S {
                let x = 0.3 * i as f64 + 0.5 * c as f64 + 0.9 * s as f64;
                shapedirs.push((0.01 * x.cos()) as f32);
            }
            for p in 0..NUM_POSE_FEATURES {
                let x = 0.11 * i as f64 + 0.7 * c as f64 + 0.013 * p as f64;
                posedirs.push((0.001 * x.sin()) as f32);
            }
        }
    }
    BodyModel::new(
        v_template,
        shapedirs,
        posedirs,
        golden_regressor(),
        golden_weights(),
        SMPL_PARENTS.to_vec(),
        vec![[0, 1, 2]],
    )
    .expect("golden model is valid")
}

/// The script's joint regressor: two vertices per joint.
fn golden_regressor() -> Vec<Vec<(u32, f32)>> {
    (0..NUM_JOINTS)
        .map(|k| vec![((k % V) as u32, 0.6), (((5 * k + 3) % V) as u32, 0.4)])
        .collect()
}

/// The script's skinning weights: every joint, falling off with a scrambled index distance.
fn golden_weights() -> Vec<[f32; NUM_JOINTS]> {
    (0..V)
        .map(|i| {
            let raw: Vec<f64> = (0..NUM_JOINTS)
                .map(|k| 1.0 / (1.0 + ((k * 7 + i * 5) % 24) as f64).powi(2))
                .collect();
            let sum: f64 = raw.iter().sum();
            let mut w = [0.0f32; NUM_JOINTS];
            for (wk, r) in w.iter_mut().zip(&raw) {
                *wk = (r / sum) as f32;
            }
            w
        })
        .collect()
}

#[test]
fn lbs_matches_the_smplx_reference() {
    let model = golden_model();
    let mut poses = [0.0f32; 72];
    for j in 0..NUM_JOINTS {
        for c in 0..3 {
            poses[3 * j + c] = (0.4 * (1.7 * j as f64 + 2.3 * c as f64).sin()) as f32;
        }
    }
    let posed = model.lbs(&SmplParams {
        poses,
        shapes: vec![0.5, -1.2, 2.0],
        rh: Vec3::new(0.3, -0.5, 0.8),
        th: Vec3::new(0.1, 0.2, -0.3),
    });
    let check = |got: &[Vec3], want: &[[f64; 3]], what: &str| {
        assert_eq!(got.len(), want.len());
        for (i, (g, w)) in got.iter().zip(want).enumerate() {
            let w = Vec3::new(w[0] as f32, w[1] as f32, w[2] as f32);
            assert!(g.distance(w) < GOLDEN_TOL_M, "{what} {i}: {g} vs {w}");
        }
    };
    check(&posed.vertices, &GOLDEN_VERTICES, "vertex");
    check(&posed.joints, &GOLDEN_JOINTS, "joint");
}
