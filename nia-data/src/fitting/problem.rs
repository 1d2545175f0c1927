//! A fit as the solver sees it: frames of a body under one [`Freedom`], the energy
//!
//! `E = (1 / B) [ sum_b (E_kp,b + E_sil,b + priors_b) + w_beta |beta|^2 ]`
//!
//! over the `B` frames (one but for `prepare`'s shape stage), its linearisation in the step's
//! parameters ([`super::body`]) and the step itself.

use glam::{Quat, Vec3};

use super::body::{joint_changes, Arms, BodyPoints, FrameState, Freedom, PosedPoints};
use super::keypoints::KeypointTerms;
use super::priors::Priors;
use super::silhouette::{Residual, SilhouetteTerms};
use super::solver::{LeastSquares, NormalEquations};

/// One frame of a fit: its body, what it sees and its priors.
pub(crate) struct FrameTerms<'a> {
    pub body: BodyPoints<'a>,
    pub silhouettes: SilhouetteTerms<'a>,
    pub keypoints: Option<KeypointTerms<'a>>,
    pub priors: Priors,
}

/// How far a fit may move from its start (the loader's alignment: its bounds).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Bounds {
    pub max_translation_m: f32,
    pub max_rotation_rad: f32,
    /// The largest rotation of a body joint from the start.
    pub max_joint_rad: f32,
}

/// Frames under one freedom (module docs).
pub(crate) struct Problem<'a> {
    pub freedom: Freedom,
    pub frames: Vec<FrameTerms<'a>>,
    /// `w_beta` ([`Freedom::Full`]).
    pub shape_prior: f32,
    /// The states the bounds measure from, and the bounds (`None`: free).
    pub bounds: Option<(Vec<FrameState>, Vec<Vec3>, Bounds)>,
}

impl<'a> Problem<'a> {
    /// Step parameters in all: each frame's, then the shared betas'.
    fn params(&self, betas: usize) -> usize {
        let shared = if self.freedom == Freedom::Full {
            betas
        } else {
            0
        };
        self.frames.len() * self.freedom.frame_params() + shared
    }

    /// Keeps `start` (and the centres of its posed points) as what the bounds measure from.
    pub fn bounded(mut self, start: &[FrameState], bounds: Bounds) -> Self {
        let centres = self
            .frames
            .iter()
            .zip(start)
            .map(|(f, s)| f.body.pose(s).centre)
            .collect();
        self.bounds = Some((start.to_vec(), centres, bounds));
        self
    }

    /// Adds frame `b`'s image terms' residuals to `system`, its points at `posed`.
    fn linearise_images(
        &self,
        b: usize,
        state: &FrameState,
        posed: &PosedPoints,
        system: &mut NormalEquations,
        scale: f32,
    ) {
        let frame = &self.frames[b];
        let freedom = self.freedom;
        let offset = b * freedom.frame_params();
        let betas_at = self.frames.len() * freedom.frame_params();
        let (beta_vertices, beta_keypoints) = if freedom == Freedom::Full {
            frame.body.beta_columns(&state.params)
        } else {
            (Vec::new(), Vec::new())
        };
        let mut row: Vec<(usize, f32)> = Vec::with_capacity(freedom.frame_params() + 16);
        let mut add = |arms: &Arms, betas: &[Vec3], res: Residual| {
            row.clear();
            let g = arms.global.cross(res.a);
            let t = res.a * arms.translation;
            row.extend([
                (offset, g.x),
                (offset + 1, g.y),
                (offset + 2, g.z),
                (offset + 3, t.x),
                (offset + 4, t.y),
                (offset + 5, t.z),
            ]);
            for &(k, m) in &arms.joints {
                let d = m.cross(res.a);
                let p = offset + 6 + 3 * (k - 1);
                row.extend([(p, d.x), (p + 1, d.y), (p + 2, d.z)]);
            }
            for (j, d) in betas.iter().enumerate() {
                row.push((betas_at + j, d.dot(res.a)));
            }
            system.add(&row, res.r, res.w * scale);
        };
        let silhouette_points = &posed.vertices[..frame.body.silhouette_len];
        let vertex_arms: Vec<_> = (0..silhouette_points.len())
            .map(|p| frame.body.vertex_arms(posed, p, freedom))
            .collect();
        let column = |columns: &[Vec<Vec3>], i: usize| -> Vec<Vec3> {
            columns.iter().map(|c| c[i]).collect()
        };
        frame.silhouettes.energy(
            silhouette_points,
            Some(&mut |res: Residual| {
                add(
                    &vertex_arms[res.index],
                    &column(&beta_vertices, res.index),
                    res,
                )
            }),
        );
        if let Some(keypoints) = &frame.keypoints {
            let kp_arms: Vec<_> = (0..posed.keypoints.len())
                .map(|k| frame.body.keypoint_arms(posed, k, freedom))
                .collect();
            keypoints.energy(
                &posed.keypoints,
                Some(&mut |res: Residual| {
                    add(
                        &kp_arms[res.index],
                        &column(&beta_keypoints, res.index),
                        res,
                    )
                }),
            );
        }
    }
}

impl<'a> LeastSquares for Problem<'a> {
    type State = Vec<FrameState>;
    type Evaluated = Vec<PosedPoints>;

    fn evaluate(&self, state: &Self::State) -> (f32, Self::Evaluated) {
        let mut energy = 0.0f32;
        let mut posed = Vec::with_capacity(self.frames.len());
        for (frame, s) in self.frames.iter().zip(state) {
            let p = frame.body.pose(s);
            energy += frame
                .silhouettes
                .energy(&p.vertices[..frame.body.silhouette_len], None);
            if let Some(k) = &frame.keypoints {
                energy += k.energy(&p.keypoints, None);
            }
            energy += frame.priors.energy(s);
            posed.push(p);
        }
        if self.freedom == Freedom::Full {
            if let Some(s) = state.first() {
                energy += self.shape_prior * s.params.shapes.iter().map(|b| b * b).sum::<f32>();
            }
        }
        (energy / self.frames.len().max(1) as f32, posed)
    }

    fn linearise(&self, state: &Self::State, at: &Self::Evaluated) -> NormalEquations {
        let betas = state.first().map_or(0, |s| s.params.shapes.len());
        let mut system = NormalEquations::new(self.params(betas));
        let scale = 1.0 / self.frames.len().max(1) as f32;
        for (b, (s, posed)) in state.iter().zip(at).enumerate() {
            self.linearise_images(b, s, posed, &mut system, scale);
            if self.freedom != Freedom::Rigid {
                let offset = b * self.freedom.frame_params();
                // The priors' rows at the frame's offset, weights scaled by 1 / B.
                let scaled = Priors {
                    pose: self.frames[b]
                        .priors
                        .pose
                        .clone()
                        .map(|(r, w)| (r, w * scale)),
                    limits: self.frames[b].priors.limits * scale,
                    temporal: self.frames[b]
                        .priors
                        .temporal
                        .clone()
                        .map(|(p, w, wt)| (p, w * scale, wt * scale)),
                };
                scaled.linearise(&self.frames[b].body, s, posed, &mut system, offset);
            }
        }
        if self.freedom == Freedom::Full {
            if let Some(s) = state.first() {
                let at = self.frames.len() * self.freedom.frame_params();
                for (j, &beta) in s.params.shapes.iter().enumerate() {
                    system.add(&[(at + j, 1.0)], beta, self.shape_prior * scale);
                }
            }
        }
        system
    }

    fn step(&self, state: &Self::State, at: &Self::Evaluated, delta: &[f64]) -> Self::State {
        let per = self.freedom.frame_params();
        let betas_delta = &delta[(self.frames.len() * per).min(delta.len())..];
        self.frames
            .iter()
            .zip(state.iter().zip(at))
            .enumerate()
            .map(|(b, (frame, (s, posed)))| {
                frame.body.step(
                    s,
                    posed,
                    self.freedom,
                    &delta[b * per..(b + 1) * per],
                    betas_delta,
                )
            })
            .collect()
    }

    fn within(&self, state: &Self::State, at: &Self::Evaluated) -> bool {
        let Some((start, centres, bounds)) = &self.bounds else {
            return true;
        };
        state
            .iter()
            .zip(at)
            .zip(start.iter().zip(centres))
            .all(|((s, posed), (s0, c0))| {
                let moved = posed.centre.distance(*c0) <= bounds.max_translation_m;
                let turned = match self.freedom {
                    Freedom::Rigid => s.rigid.rotation.angle_between(Quat::IDENTITY),
                    _ => Quat::from_scaled_axis(s.params.rh)
                        .angle_between(Quat::from_scaled_axis(s0.params.rh)),
                } <= bounds.max_rotation_rad;
                let joints = self.freedom == Freedom::Rigid
                    || joint_changes(&s.params, &s0.params)
                        .iter()
                        .skip(1)
                        .all(|q| q.angle_between(Quat::IDENTITY) <= bounds.max_joint_rad);
                moved && turned && joints
            })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::body::SmplParams;
    use crate::body::{pose_for_motion, BodyModel, MotionKind, ProceduralBody, ProceduralSpec};
    use crate::fitting::body::RigidMotion;
    use crate::fitting::keypoints::{KeypointBinding, KeypointView};
    use crate::fitting::projection::Pixels;
    use crate::geometry::camera::Camera;

    /// Central differences of an f32 energy against the rows (which leave out the pose blend
    /// shapes): measured 1.7e-4 relative for both freedoms.
    const GRADIENT_REL_TOL: f64 = 1e-2;

    fn model() -> BodyModel {
        ProceduralBody::generate(&ProceduralSpec {
            target_vertices: 800,
            ..ProceduralSpec::default()
        })
        .unwrap()
    }

    fn params(phase: f32, shape: f32) -> SmplParams {
        let mut poses = pose_for_motion(phase, MotionKind::Walk);
        poses[..3].fill(0.0);
        SmplParams {
            poses,
            shapes: vec![shape, -0.3, 0.2, 0.0, 0.1, 0.0, 0.0, 0.0, 0.0, 0.0],
            rh: Vec3::new(1.2, 0.3, -0.2),
            th: Vec3::new(0.1, -0.05, 0.9),
        }
    }

    /// The step rows (`g` of the normal equations: half the energy's gradient) of the
    /// keypoint term and every prior, under `Joints` and `Full`, against central differences
    /// of the energy along each step parameter.
    #[test]
    fn the_step_rows_are_the_energys_gradient() {
        let model = model();
        let cams: Vec<Camera> = (0..3)
            .map(|i| {
                let a = i as f32 * 2.1 + 0.3;
                let eye = Vec3::new(0.1 + 3.0 * a.cos(), -0.05 + 3.0 * a.sin(), 1.3);
                Camera::look_at(
                    eye,
                    Vec3::new(0.1, -0.05, 0.9),
                    Vec3::Z,
                    200.0,
                    200.0,
                    128,
                    128,
                )
                .unwrap()
            })
            .collect();
        let bindings: Vec<KeypointBinding> = (0..22)
            .map(KeypointBinding::joint)
            .chain([KeypointBinding::vertex(5), KeypointBinding::midpoint(1, 2)])
            .collect();
        let truth = model.lbs(&params(0.7, 0.4));
        let detections: Vec<Vec<[f32; 3]>> = cams
            .iter()
            .map(|c| {
                bindings
                    .iter()
                    .map(|b| {
                        let x: Vec3 = b
                            .joints
                            .iter()
                            .map(|&(j, w)| truth.joints[j] * w)
                            .sum::<Vec3>()
                            + b.vertices
                                .iter()
                                .map(|&(v, w)| truth.vertices[v] * w)
                                .sum::<Vec3>();
                        let uv = c.project(x).unwrap().0;
                        [uv.x, uv.y, 1.0]
                    })
                    .collect()
            })
            .collect();
        let start = params(0.3, 0.0);
        let prev = params(0.35, 0.0);
        for freedom in [Freedom::Joints, Freedom::Full] {
            let body = BodyPoints::with_model(&model, &[], &bindings, &start, None);
            let problem = Problem {
                freedom,
                frames: vec![FrameTerms {
                    body,
                    silhouettes: SilhouetteTerms {
                        views: Vec::new(),
                        weight_out: 0.0,
                        weight_in: 0.0,
                    },
                    keypoints: Some(KeypointTerms {
                        views: cams
                            .iter()
                            .zip(&detections)
                            .map(|(camera, keypoints)| KeypointView {
                                camera,
                                pixels: Pixels::Pinhole,
                                keypoints,
                            })
                            .collect(),
                        bindings: &bindings,
                        // Large: the keypoint term nearly quadratic, its weights smooth.
                        sigma2: 1e6,
                        torso_only: false,
                        offset_prone_weight: 1.0,
                    }),
                    priors: Priors {
                        pose: Some((
                            SmplParams {
                                poses: [0.0; 72],
                                ..start.clone()
                            },
                            0.5,
                        )),
                        limits: 3.0,
                        temporal: Some((prev.clone(), 2.0, 50.0)),
                    },
                }],
                shape_prior: 0.7,
                bounds: None,
            };
            let state = vec![FrameState {
                params: start.clone(),
                rigid: RigidMotion::identity(Vec3::ZERO),
            }];
            let (_, at) = problem.evaluate(&state);
            let system = problem.linearise(&state, &at);
            let g = system.gradient();
            let h = 1e-3f64;
            let mut numeric = vec![0.0f64; g.len()];
            for (i, n) in numeric.iter_mut().enumerate() {
                let mut delta = vec![0.0f64; g.len()];
                delta[i] = h;
                let plus = problem.evaluate(&problem.step(&state, &at, &delta)).0 as f64;
                delta[i] = -h;
                let minus = problem.evaluate(&problem.step(&state, &at, &delta)).0 as f64;
                *n = 0.5 * (plus - minus) / (2.0 * h);
            }
            let norm = |v: &[f64]| v.iter().map(|x| x * x).sum::<f64>().sqrt();
            let diff: Vec<f64> = g.iter().zip(&numeric).map(|(a, b)| a - b).collect();
            let rel = norm(&diff) / norm(&numeric);
            assert!(
                rel < GRADIENT_REL_TOL,
                "{freedom:?}: rows against differences {rel} (|g| {}, |numeric| {})",
                norm(g),
                norm(&numeric)
            );
        }
    }
}
