//! Motion-only bundle adjustment over every camera of a rig (eqs. 1-3 of Kokas et al.).
//!
//! The landmarks are fixed; only the rig's pose is optimized. A landmark `X` (world)
//! seen by camera `c` at pixel `x` at pyramid level `l` contributes the reprojection
//! residual
//!
//! ```text
//! r = x - π(K_c · (camera_c_from_body · body_from_world · X))          (eqs. 2, 3)
//! ```
//!
//! weighted by the inverse variance of a keypoint at that level (`σ = scale_factor^l`
//! pixels) and a Huber kernel on its χ² (eq. 1). The paper's reference lens is the rig's
//! body frame here: observations of the rear pair enter through their URDF extrinsics,
//! so a landmark seen by any camera constrains the same six parameters.
//!
//! The solver is Levenberg-Marquardt on the 6×6 normal equations with the pose updated on
//! the left, `body_from_world ← Exp(δ) · body_from_world`, `δ = (ω, v)`; the analytic
//! Jacobian is `∂r/∂δ = -∂π/∂p_c · R_cb · [-[p_b]× | I]` (checked against numeric
//! differentiation in the tests). As in ORB-SLAM, it runs in rounds: after each round the
//! observations whose χ² exceeds the 2-DOF 95 % quantile are set aside as outliers (and
//! may come back in a later round), and the last round drops the robust kernel.

use nalgebra::{
    Isometry3, Matrix2x6, Matrix6, Point3, Translation3, UnitQuaternion, Vector2, Vector3, Vector6,
};

use super::{ConfigError, check};

/// χ² of a 2-DOF residual at 95 %: the outlier threshold (and Huber width²) in units of
/// the keypoint's standard deviation.
pub const CHI2_2DOF_95: f64 = 5.991;

/// Nearest a landmark may be in front of a camera to count, m.
const MIN_DEPTH_M: f64 = 1e-3;

/// One camera of the rig: rectified pinhole intrinsics and where it sits on the body.
#[derive(Clone, Debug, PartialEq)]
pub struct RigCamera {
    /// Focal lengths, px.
    pub fx: f64,
    /// Focal length along y, px.
    pub fy: f64,
    /// Principal point x, px.
    pub cx: f64,
    /// Principal point y, px.
    pub cy: f64,
    /// `body_from_camera` (optical frame: x right, y down, z forward).
    pub body_from_camera: Isometry3<f64>,
}

impl RigCamera {
    /// The pixel of a point in this camera's optical frame (`None` behind the camera).
    pub fn project(&self, p_c: &Vector3<f64>) -> Option<Vector2<f64>> {
        (p_c.z > MIN_DEPTH_M).then(|| {
            Vector2::new(
                self.fx * p_c.x / p_c.z + self.cx,
                self.fy * p_c.y / p_c.z + self.cy,
            )
        })
    }
}

/// A landmark matched to a keypoint in one camera of the current frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Observation {
    /// Index of the camera in the rig.
    pub camera: usize,
    /// The landmark, in `world`.
    pub landmark_in_world: Vector3<f64>,
    /// The keypoint, px.
    pub pixel: Vector2<f64>,
    /// The keypoint's pyramid level.
    pub level: u8,
}

/// Settings of [`optimize_pose`].
#[derive(Clone, Debug, PartialEq)]
pub struct MotionBaConfig {
    /// Outlier-classification rounds (ORB-SLAM: 4).
    pub rounds: usize,
    /// Levenberg-Marquardt iterations per round (ORB-SLAM: 10).
    pub iterations_per_round: usize,
    /// Pyramid scale factor: a keypoint at level `l` has `σ = scale_factor^l` px.
    pub scale_factor: f64,
    /// χ² above which an observation is an outlier (2 DOF, in σ units).
    pub chi2_threshold: f64,
    /// Fewest inliers for a pose to be returned.
    pub min_inliers: usize,
}

impl Default for MotionBaConfig {
    fn default() -> MotionBaConfig {
        MotionBaConfig {
            rounds: 4,
            iterations_per_round: 10,
            scale_factor: 1.2,
            chi2_threshold: CHI2_2DOF_95,
            min_inliers: 10,
        }
    }
}

impl MotionBaConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(
            (1..=20).contains(&self.rounds),
            "motion BA rounds must be in [1, 20]",
        )?;
        check(
            (1..=100).contains(&self.iterations_per_round),
            "motion BA iterations per round must be in [1, 100]",
        )?;
        check(
            self.scale_factor.is_finite() && self.scale_factor >= 1.0,
            "the pyramid scale factor must be at least 1",
        )?;
        check(
            self.chi2_threshold.is_finite() && self.chi2_threshold > 0.0,
            "the χ² threshold must be positive",
        )?;
        check(self.min_inliers >= 3, "motion BA needs at least 3 inliers")
    }
}

/// What [`optimize_pose`] found.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseEstimate {
    /// The optimized rig pose.
    pub world_from_body: Isometry3<f64>,
    /// Per observation: an inlier of the final round.
    pub inliers: Vec<bool>,
    /// Number of inliers.
    pub n_inliers: usize,
    /// Sum of the inliers' χ² at the end (σ units).
    pub chi2: f64,
}

/// Why no pose came out.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum MotionBaError {
    /// An observation names a camera the rig does not have.
    #[error("observation {index} names camera {camera}, the rig has {cameras}")]
    UnknownCamera {
        /// The observation.
        index: usize,
        /// Its camera.
        camera: usize,
        /// Cameras in the rig.
        cameras: usize,
    },
    /// Too few observations agree with any pose.
    #[error("{inliers} inliers after motion-only BA, at least {needed} needed")]
    TooFewInliers {
        /// Inliers left.
        inliers: usize,
        /// The configured minimum.
        needed: usize,
    },
}

/// Residual and its Jacobian for one observation at `body_from_world`.
///
/// `r = pixel - π(p_c)`, `J = ∂r/∂δ` for the left update `Exp(δ) · body_from_world` with
/// `δ = (ω, v)`. `None` when the landmark is behind the camera.
pub fn residual_and_jacobian(
    camera: &RigCamera,
    body_from_world: &Isometry3<f64>,
    obs: &Observation,
) -> Option<(Vector2<f64>, Matrix2x6<f64>)> {
    let p_b = body_from_world * Point3::from(obs.landmark_in_world);
    let camera_from_body = camera.body_from_camera.inverse();
    let p_c = (camera_from_body * p_b).coords;
    let predicted = camera.project(&p_c)?;
    let z_inv = 1.0 / p_c.z;
    let d_proj = nalgebra::Matrix2x3::new(
        camera.fx * z_inv,
        0.0,
        -camera.fx * p_c.x * z_inv * z_inv,
        0.0,
        camera.fy * z_inv,
        -camera.fy * p_c.y * z_inv * z_inv,
    );
    let r_cb = camera_from_body.rotation.to_rotation_matrix();
    let mut d_pb = nalgebra::Matrix3x6::zeros();
    d_pb.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-p_b.coords.cross_matrix()));
    d_pb.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&nalgebra::Matrix3::identity());
    let jacobian = -(d_proj * r_cb.matrix() * d_pb);
    Some((obs.pixel - predicted, jacobian))
}

/// The left update `Exp(δ) · pose` (rotation by the axis-angle `δ[0..3]`, then the
/// translation `δ[3..6]`).
pub fn retract(delta: &Vector6<f64>, pose: &Isometry3<f64>) -> Isometry3<f64> {
    let step = Isometry3::from_parts(
        Translation3::new(delta[3], delta[4], delta[5]),
        UnitQuaternion::from_scaled_axis(Vector3::new(delta[0], delta[1], delta[2])),
    );
    step * pose
}

/// The Huber weight of a residual with `chi2` (σ units) for a kernel of width
/// `sqrt(threshold)`: 1 inside, `width / |r|` outside.
fn huber_weight(chi2: f64, threshold: f64) -> f64 {
    let width = threshold.sqrt();
    let norm = chi2.sqrt();
    if norm <= width { 1.0 } else { width / norm }
}

/// Motion-only BA: the rig pose that best explains `observations` (eq. 1), from `guess`
/// (e.g. the constant-velocity prediction).
pub fn optimize_pose(
    rig: &[RigCamera],
    observations: &[Observation],
    guess: &Isometry3<f64>,
    cfg: &MotionBaConfig,
) -> Result<PoseEstimate, MotionBaError> {
    for (index, o) in observations.iter().enumerate() {
        if o.camera >= rig.len() {
            return Err(MotionBaError::UnknownCamera {
                index,
                camera: o.camera,
                cameras: rig.len(),
            });
        }
    }
    let info: Vec<f64> = observations
        .iter()
        .map(|o| cfg.scale_factor.powi(-2 * i32::from(o.level)))
        .collect();
    let chi2_of = |pose: &Isometry3<f64>, i: usize| {
        let o = &observations[i];
        residual_and_jacobian(&rig[o.camera], pose, o).map(|(r, _)| r.norm_squared() * info[i])
    };
    let mut body_from_world = guess.inverse();
    let mut inliers = vec![true; observations.len()];
    for round in 0..cfg.rounds {
        let robust = round + 1 < cfg.rounds;
        let cost = |pose: &Isometry3<f64>, inliers: &[bool]| -> f64 {
            (0..observations.len())
                .filter(|&i| inliers[i])
                .map(|i| match chi2_of(pose, i) {
                    Some(c) if robust => {
                        // Huber: quadratic inside, linear outside (in |r|).
                        let w = cfg.chi2_threshold;
                        if c <= w { c } else { 2.0 * (w * c).sqrt() - w }
                    }
                    Some(c) => c,
                    None => cfg.chi2_threshold * 4.0,
                })
                .sum()
        };
        let mut lambda = 1e-3;
        let mut current = cost(&body_from_world, &inliers);
        for _ in 0..cfg.iterations_per_round {
            let mut h = Matrix6::zeros();
            let mut g = Vector6::zeros();
            for (i, o) in observations.iter().enumerate() {
                if !inliers[i] {
                    continue;
                }
                let Some((r, j)) = residual_and_jacobian(&rig[o.camera], &body_from_world, o)
                else {
                    continue;
                };
                let chi2 = r.norm_squared() * info[i];
                let w = info[i]
                    * if robust {
                        huber_weight(chi2, cfg.chi2_threshold)
                    } else {
                        1.0
                    };
                h += j.transpose() * j * w;
                g -= j.transpose() * r * w;
            }
            // Levenberg-Marquardt: damp until the step lowers the cost.
            let mut improved = false;
            for _ in 0..10 {
                let mut damped = h;
                for k in 0..6 {
                    damped[(k, k)] += lambda * h[(k, k)].max(1e-9);
                }
                let Some(chol) = damped.cholesky() else {
                    lambda *= 10.0;
                    continue;
                };
                let delta = chol.solve(&g);
                let candidate = retract(&delta, &body_from_world);
                let c = cost(&candidate, &inliers);
                if c < current {
                    body_from_world = candidate;
                    current = c;
                    lambda = (lambda / 10.0).max(1e-9);
                    improved = delta.norm() > 1e-12;
                    break;
                }
                lambda *= 10.0;
            }
            if !improved {
                break;
            }
        }
        // Classify every observation (set-aside ones may come back).
        for (i, inlier) in inliers.iter_mut().enumerate() {
            *inlier = chi2_of(&body_from_world, i).is_some_and(|c| c <= cfg.chi2_threshold);
        }
        if inliers.iter().filter(|&&b| b).count() < cfg.min_inliers {
            break;
        }
    }
    let n_inliers = inliers.iter().filter(|&&b| b).count();
    if n_inliers < cfg.min_inliers {
        return Err(MotionBaError::TooFewInliers {
            inliers: n_inliers,
            needed: cfg.min_inliers,
        });
    }
    let chi2 = (0..observations.len())
        .filter(|&i| inliers[i])
        .filter_map(|i| chi2_of(&body_from_world, i))
        .sum();
    Ok(PoseEstimate {
        world_from_body: body_from_world.inverse(),
        inliers,
        n_inliers,
        chi2,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    fn rig() -> Vec<RigCamera> {
        crate::slam::bench::synthetic_rig()
    }

    fn truth() -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::new(12.0, -3.5, 0.2),
            UnitQuaternion::from_euler_angles(0.02, -0.03, 0.7),
        )
    }

    /// Landmarks around the robot that a camera sees, with their true pixels (plus
    /// `noise_px` of Gaussian noise), at random pyramid levels 0..4.
    fn observations(
        world_from_body: &Isometry3<f64>,
        n: usize,
        noise_px: f64,
        seed: u64,
    ) -> Vec<Observation> {
        let rig = rig();
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let noise = Normal::new(0.0, noise_px.max(1e-12)).unwrap();
        let mut out = Vec::new();
        while out.len() < n {
            let camera = out.len() % rig.len();
            // A point 2 to 12 m in front of that camera, within its view.
            let p_c = Vector3::new(
                rng.random_range(-0.8..0.8),
                rng.random_range(-0.5..0.5),
                1.0,
            ) * rng.random_range(2.0..12.0);
            let p_w = world_from_body * (rig[camera].body_from_camera * Point3::from(p_c));
            let level: u8 = rng.random_range(0..4);
            let sigma = 1.2_f64.powi(i32::from(level));
            let pixel = rig[camera].project(&p_c).unwrap()
                + Vector2::new(noise.sample(&mut rng), noise.sample(&mut rng)) * sigma;
            out.push(Observation {
                camera,
                landmark_in_world: p_w.coords,
                pixel,
                level,
            });
        }
        out
    }

    fn errors(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
        let d = a.inverse() * b;
        (d.translation.vector.norm(), d.rotation.angle().to_degrees())
    }

    fn nudged(pose: &Isometry3<f64>) -> Isometry3<f64> {
        retract(&Vector6::new(0.02, -0.015, 0.03, 0.15, -0.1, 0.05), pose)
    }

    #[test]
    fn the_jacobian_matches_numeric_differentiation() {
        let rig = rig();
        let body_from_world = truth().inverse();
        let obs = observations(&truth(), 40, 1.0, 1);
        let h = 1e-6;
        for o in &obs {
            let cam = &rig[o.camera];
            let (_, j) = residual_and_jacobian(cam, &body_from_world, o).unwrap();
            for k in 0..6 {
                let mut d = Vector6::zeros();
                d[k] = h;
                let (plus, _) =
                    residual_and_jacobian(cam, &retract(&d, &body_from_world), o).unwrap();
                d[k] = -h;
                let (minus, _) =
                    residual_and_jacobian(cam, &retract(&d, &body_from_world), o).unwrap();
                let numeric = (plus - minus) / (2.0 * h);
                let analytic = j.column(k);
                assert!(
                    (numeric - analytic).norm() < 1e-4 * (1.0 + analytic.norm()),
                    "camera {} column {k}: numeric {numeric:?} vs analytic {analytic:?}",
                    o.camera
                );
            }
        }
    }

    #[test]
    fn exact_observations_from_both_cameras_give_the_true_pose() {
        let obs = observations(&truth(), 60, 0.0, 2);
        let est =
            optimize_pose(&rig(), &obs, &nudged(&truth()), &MotionBaConfig::default()).unwrap();
        let (t, r) = errors(&est.world_from_body, &truth());
        assert!(t < 1e-7 && r < 1e-6, "{t} m, {r}°");
        assert_eq!(est.n_inliers, obs.len());
        assert!(est.chi2 < 1e-9, "{}", est.chi2);
    }

    #[test]
    fn the_rear_camera_alone_fixes_the_pose_through_its_extrinsics() {
        // Only landmarks behind the robot (camera 1): eq. 2's R_CV, t_CV carry them to the
        // body. Ignoring the extrinsics (treating them as front-camera pixels) fails.
        let obs: Vec<Observation> = observations(&truth(), 80, 0.5, 3)
            .into_iter()
            .filter(|o| o.camera == 1)
            .collect();
        let est =
            optimize_pose(&rig(), &obs, &nudged(&truth()), &MotionBaConfig::default()).unwrap();
        let (t, r) = errors(&est.world_from_body, &truth());
        assert!(t < 0.02 && r < 0.2, "{t} m, {r}°");
        let as_front: Vec<Observation> = obs
            .iter()
            .map(|o| Observation {
                camera: 0,
                ..o.clone()
            })
            .collect();
        let wrong = optimize_pose(
            &rig(),
            &as_front,
            &nudged(&truth()),
            &MotionBaConfig::default(),
        );
        assert!(
            failed_or_off_by(&wrong, 0.5),
            "front-camera interpretation should not explain rear observations"
        );
    }

    /// True when `result` is an error or a pose more than `m` metres from the truth.
    fn failed_or_off_by(result: &Result<PoseEstimate, MotionBaError>, m: f64) -> bool {
        match result {
            Err(_) => true,
            Ok(e) => errors(&e.world_from_body, &truth()).0 > m,
        }
    }

    #[test]
    fn noise_and_gross_outliers_are_handled_like_orb_slam() {
        // 1 px noise (scaled by level), and a quarter of the matches wrong by 20-80 px.
        let mut obs = observations(&truth(), 200, 1.0, 4);
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let mut wrong = vec![false; obs.len()];
        for (i, o) in obs.iter_mut().enumerate() {
            if i % 4 == 1 {
                let angle: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                o.pixel += Vector2::new(angle.cos(), angle.sin()) * rng.random_range(20.0..80.0);
                wrong[i] = true;
            }
        }
        let est =
            optimize_pose(&rig(), &obs, &nudged(&truth()), &MotionBaConfig::default()).unwrap();
        let (t, r) = errors(&est.world_from_body, &truth());
        assert!(t < 0.02 && r < 0.1, "{t} m, {r}°");
        // Every wrong match rejected; of the right ones at most 10 % (the χ² test at 95 %
        // rejects 5 % of exact-noise inliers).
        assert!(wrong.iter().zip(&est.inliers).all(|(w, i)| !(*w && *i)));
        let right = wrong.iter().filter(|w| !**w).count();
        let kept = wrong
            .iter()
            .zip(&est.inliers)
            .filter(|(w, i)| !**w && **i)
            .count();
        assert!(kept as f64 > 0.9 * right as f64, "{kept} of {right}");
        // Without the rounds (one round, no kernel, no rejection) the outliers pull the
        // pose away: the rounds are what make it robust.
        let plain = MotionBaConfig {
            rounds: 1,
            ..MotionBaConfig::default()
        };
        let naive = optimize_pose(&rig(), &obs, &nudged(&truth()), &plain);
        assert!(failed_or_off_by(&naive, 5.0 * t.max(0.005)));
    }

    #[test]
    fn coarse_keypoints_weigh_less() {
        // One observation 6 px off among exact ones: at level 0 (σ = 1 px, χ² = 36 > 5.99)
        // it is rejected, at level 7 (σ = 3.58 px, χ² = 2.8) it is kept with a weight
        // 1/12.8 of a level-0 one and moves the pose a little.
        let base = observations(&truth(), 30, 0.0, 6);
        let cfg = MotionBaConfig {
            min_inliers: 5,
            ..MotionBaConfig::default()
        };
        let with = |level: u8| {
            let mut obs = base.clone();
            obs[0].pixel += Vector2::new(6.0, 0.0);
            obs[0].level = level;
            optimize_pose(&rig(), &obs, &nudged(&truth()), &cfg).unwrap()
        };
        let fine = with(0);
        let coarse = with(7);
        assert!(!fine.inliers[0], "a 6σ error at level 0 is an outlier");
        assert!(coarse.inliers[0], "a 1.7σ error at level 7 is not");
        // The kept coarse observation moves the pose, but by little.
        let (t, _) = errors(&coarse.world_from_body, &truth());
        assert!(t > 0.0 && t < 5e-3, "{t} m");
    }

    #[test]
    fn bad_input_is_an_error() {
        let mut obs = observations(&truth(), 12, 0.0, 7);
        let cfg = MotionBaConfig::default();
        assert!(matches!(
            optimize_pose(&rig(), &obs[..5], &truth(), &cfg),
            Err(MotionBaError::TooFewInliers {
                inliers: 5,
                needed: 10
            })
        ));
        obs[3].camera = 2;
        assert_eq!(
            optimize_pose(&rig(), &obs, &truth(), &cfg),
            Err(MotionBaError::UnknownCamera {
                index: 3,
                camera: 2,
                cameras: 2
            })
        );
        assert!(
            MotionBaConfig {
                scale_factor: 0.5,
                ..cfg.clone()
            }
            .validate()
            .is_err()
        );
        assert!(
            MotionBaConfig {
                min_inliers: 2,
                ..cfg.clone()
            }
            .validate()
            .is_err()
        );
        assert!(cfg.validate().is_ok());
    }
}
