//! Local and global bundle adjustment (eqs. 4-5 of Kokas et al.).
//!
//! Keyframe poses and landmark positions are refined together over the observations of
//! every camera of the rig. A landmark `X` (world) seen by camera `c` of keyframe `k` at
//! pixel `(u, v)` of pyramid level `l` contributes the reprojection residual
//!
//! ```text
//! r = (u, v) - π(K_c · camera_c_from_body · body_from_world_k · X)          (monocular)
//! r = (u, v, u_r) - (π(p_c), π_u(p_c) - f_x · b / z_c)                      (stereo)
//! ```
//!
//! the stereo form being ORB-SLAM's `EdgeStereoSE3ProjectXYZ` (`u_r`: the column of the
//! match in the right rectified image, `b` the pair's baseline). Each residual is weighted
//! by the inverse variance of a keypoint at its level, `scale_factor^(-2·l)`·I, and, in
//! the robust rounds, by a Huber kernel of width `sqrt(χ²₉₅)` on its χ² (eq. 4). Local BA
//! (eq. 4) optimizes the keyframes covisible with the current one and their landmarks,
//! with the other keyframes that see those landmarks fixed; global BA (eq. 5) optimizes
//! every keyframe and landmark after a loop closure, with the keyframe(s) whose pose the
//! closure provides fixed. Both are [`bundle_adjust`] with the caller's choice of fixed
//! keyframes and landmarks: the function knows no covisibility, it takes the problem as
//! given.
//!
//! Conventions follow [`motion_ba`](super::motion_ba): the optimizer holds
//! `body_from_world` and updates it on the left, `body_from_world ← Exp(δ) · body_from_world`
//! with `δ = (ω, v)` ([`retract`]); landmarks are updated additively in `world`. The
//! analytic Jacobians (checked numerically in the tests) are
//!
//! ```text
//! ∂r/∂δ = -∂π/∂p_c · R_cb · [-[p_b]× | I]        ∂r/∂X = -∂π/∂p_c · R_cb · R_bw
//! ```
//!
//! with `∂π/∂p_c` the 2×3 (or, with the right column, 3×3) pinhole derivative.
//!
//! The solver is Levenberg-Marquardt on the normal equations with the Schur complement on
//! the landmarks: every free landmark's damped 3×3 block is inverted, the reduced camera
//! system over the free keyframes (6 per keyframe, in 6×6 blocks) is solved, and the
//! landmark steps follow by back-substitution. The reduced system is sparse (two keyframes
//! are coupled only when they see a landmark in common: the covisibility graph, banded
//! along the path plus the loop closures), so it is assembled in the blocks of a
//! [`BlockStructure`] and factored by the sparse block Cholesky of
//! [`block_cholesky`](super::block_cholesky), its minimum-degree order computed once per
//! call; each landmark's observations are sorted by that order, so the Schur complement
//! walks the structure's columns instead of searching them. The blocks are built from a
//! compact form of each observation (`B = Aᵀ w A`, `e = Aᵀ w r` and `p_b`, with
//! `A = ∂π/∂p_c · R_cb`), never from the full Jacobians. A step is kept only if it lowers
//! the (robust) cost; `λ` follows Nielsen's rule (after a kept step it is multiplied by
//! `max(1/3, 1 - (2ρ - 1)³)`, `ρ` the ratio of the actual to the predicted decrease;
//! after a rejected one by `ν`, which doubles each time); damping is
//! Marquardt's (`λ` times the block's diagonal, plus a floor), so a landmark seen once,
//! whose depth the data leave free, stays well-defined, and a landmark whose block still
//! cannot be inverted is held for that step. An observation whose landmark a step carries
//! behind its camera counts with its cost before the step (the step is judged on the
//! others) and drops out at the next linearization; it is reported as an outlier unless it
//! comes back in front.
//!
//! As in ORB-SLAM's `LocalBundleAdjustment`, the optimization runs in rounds: the first
//! ones with the Huber kernel, after each of which the observations whose χ² exceeds the
//! 95 % quantile (2 DOF monocular, 3 DOF stereo) or whose landmark is not in front of the
//! camera are set aside (each classification looks at every observation again, so one set
//! aside may come back), and a last round without the kernel (unless
//! [`BundleConfig::robust_final_round`]). [`BundleConfig::global`] sets nothing aside, as
//! ORB-SLAM's global BA: after a loop closure the observations of the fixed keyframe
//! disagree with the drifted map by far more than the threshold, and they are exactly the
//! ones that must pull it back. Since the Huber weights of such residuals shrink every
//! Gauss-Newton step (the drift of a 100-keyframe row then takes some 30 iterations to
//! come out), it first runs plain least-squares iterations
//! ([`BundleConfig::plain_iterations`], which close the loop in a handful), then one
//! robust round that deals with the wrong matches. 0.2°/m of heading drift over a 20 m
//! row (4° at the end) comes out in under 10 iterations
//! (`global_ba_with_the_loop_ends_fixed_corrects_drift`); metres of drift (0.1°/m over
//! 200 m, [`time_global_ba`](super::bench::time_global_ba)) only partly: such drift wants a
//! pose-graph correction first, as ORB-SLAM's essential graph, which the loop closer runs.
//!
//! **Gauge.** The problem is invariant to a rigid motion of the whole map (and, with
//! monocular observations only, to its scale): the caller fixes at least one keyframe
//! ([`BundleError::NoFixedKeyFrame`] otherwise), and with monocular observations only a
//! second one (or fixed landmarks) to fix the scale. Stereo observations fix the scale.
//!
//! **Determinism.** The linearization, the Schur complement and the cost run in parallel
//! (rayon), but every sum is taken in a fixed order (per landmark, per keyframe, per block
//! of the reduced system, in observation order; the cost serially), so the result is
//! bit-identical for the same input whatever the thread pool.

use std::ops::AddAssign;

use nalgebra::{
    Isometry3, Matrix3, Matrix3x6, Matrix6, Matrix6x3, Point3, UnitQuaternion, Vector2, Vector3,
    Vector6,
};

use rayon::prelude::*;

use super::block_cholesky::{BlockCholesky, BlockStructure};
use super::motion_ba::{CHI2_2DOF_95, RigCamera, retract};
use super::{ConfigError, check};

/// χ² of a 3-DOF residual at 95 %: the stereo outlier threshold (and Huber width²).
pub const CHI2_3DOF_95: f64 = 7.815;

/// The plain iterations before the rounds stop when a step lowers the cost by less than
/// this fraction (or [`BundleConfig::min_relative_decrease`], if larger).
const PLAIN_MIN_RELATIVE_DECREASE: f64 = 1e-4;

/// Tries of `λ` per iteration before the round gives up.
const LAMBDA_TRIES: usize = 10;

/// Absolute floor of the damping (information units), so that a parameter no observation
/// constrains still has a positive-definite block.
const DAMPING_FLOOR: f64 = 1e-6;

/// A keyframe of the problem.
#[derive(Clone, Debug, PartialEq)]
pub struct BaKeyFrame {
    /// The keyframe's rig pose (the initial guess, or the value kept when fixed).
    pub world_from_body: Isometry3<f64>,
    /// Held at `world_from_body` (no parameters).
    pub fixed: bool,
}

/// A landmark of the problem.
#[derive(Clone, Debug, PartialEq)]
pub struct BaLandmark {
    /// Position in `world`, m (the initial guess, or the value kept when fixed).
    pub position: Vector3<f64>,
    /// Held at `position` (no parameters).
    pub fixed: bool,
}

/// A landmark seen by one camera of one keyframe.
#[derive(Clone, Debug, PartialEq)]
pub struct BaObservation {
    /// Index into the keyframes.
    pub keyframe: usize,
    /// Index into the landmarks.
    pub landmark: usize,
    /// Index into the `cameras` passed to [`bundle_adjust`] (the rig's cameras, or one
    /// per keyframe and camera when the calibration differs).
    pub camera: usize,
    /// The keypoint in the (left) rectified image, px.
    pub pixel: Vector2<f64>,
    /// The keypoint's pyramid level: `σ = scale_factor^level` px.
    pub level: u8,
    /// Stereo: the column of the match in the right rectified image, px (`None`:
    /// monocular).
    pub right_x: Option<f64>,
    /// The stereo baseline, m (used only with `right_x`; must then be positive).
    pub baseline_m: f64,
}

impl BaObservation {
    /// Degrees of freedom of the residual: 3 with a right-image column, else 2.
    pub fn dof(&self) -> usize {
        if self.right_x.is_some() { 3 } else { 2 }
    }
}

/// Settings of [`bundle_adjust`].
#[derive(Clone, Debug, PartialEq)]
pub struct BundleConfig {
    /// Optimization rounds; the observations are classified after each but the last
    /// (ORB-SLAM's local BA: 2).
    pub rounds: usize,
    /// Levenberg-Marquardt iterations (linearizations) per round.
    pub iterations_per_round: usize,
    /// Pyramid scale factor: a keypoint at level `l` has `σ = scale_factor^l` px.
    pub scale_factor: f64,
    /// χ² above which a monocular observation is an outlier (2 DOF, σ units); also the
    /// Huber width².
    pub chi2_mono: f64,
    /// χ² above which a stereo observation is an outlier (3 DOF, σ units); also the Huber
    /// width².
    pub chi2_stereo: f64,
    /// Keep the Huber kernel in the last round too (every earlier round has it).
    pub robust_final_round: bool,
    /// Iterations of plain least squares over every observation before the rounds (none
    /// set aside, no kernel). After a loop closure most residuals are far outside the
    /// Huber width, where its weights shrink every Gauss-Newton step and the drift comes
    /// out over dozens of iterations; without them it comes out in a few, and the robust
    /// round that follows deals with the wrong matches. 0 for local BA.
    pub plain_iterations: usize,
    /// Initial Levenberg-Marquardt damping of every round.
    pub initial_lambda: f64,
    /// A round stops when a kept step lowers the cost by less than this fraction.
    pub min_relative_decrease: f64,
}

impl Default for BundleConfig {
    /// Local BA (eq. 4): a robust round, the outliers set aside, a plain round.
    fn default() -> BundleConfig {
        BundleConfig {
            rounds: 2,
            iterations_per_round: 10,
            scale_factor: 1.2,
            chi2_mono: CHI2_2DOF_95,
            chi2_stereo: CHI2_3DOF_95,
            robust_final_round: false,
            plain_iterations: 0,
            initial_lambda: 1e-3,
            min_relative_decrease: 1e-9,
        }
    }
}

impl BundleConfig {
    /// Local BA (eq. 4): the default.
    pub fn local() -> BundleConfig {
        BundleConfig::default()
    }

    /// Global BA (eq. 5) after a loop closure: up to 10 plain iterations, then one robust
    /// round of up to 50, no observation set aside during the optimization (the outliers
    /// are still reported).
    pub fn global() -> BundleConfig {
        BundleConfig {
            rounds: 1,
            iterations_per_round: 50,
            robust_final_round: true,
            plain_iterations: 10,
            ..BundleConfig::default()
        }
    }

    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(
            (1..=20).contains(&self.rounds),
            "bundle adjustment rounds must be in [1, 20]",
        )?;
        check(
            (1..=1000).contains(&self.iterations_per_round),
            "bundle adjustment iterations per round must be in [1, 1000]",
        )?;
        check(
            self.plain_iterations <= 1000,
            "bundle adjustment plain iterations must be at most 1000",
        )?;
        check(
            self.scale_factor.is_finite() && self.scale_factor >= 1.0,
            "the pyramid scale factor must be at least 1",
        )?;
        check(
            self.chi2_mono.is_finite()
                && self.chi2_mono > 0.0
                && self.chi2_stereo.is_finite()
                && self.chi2_stereo > 0.0,
            "the χ² thresholds must be positive",
        )?;
        check(
            self.initial_lambda.is_finite() && self.initial_lambda > 0.0,
            "the initial Levenberg-Marquardt damping must be positive",
        )?;
        check(
            self.min_relative_decrease.is_finite()
                && (0.0..1.0).contains(&self.min_relative_decrease),
            "the minimum relative cost decrease must be in [0, 1)",
        )
    }
}

/// What [`bundle_adjust`] found.
#[derive(Clone, Debug, PartialEq)]
pub struct BundleResult {
    /// Per keyframe, the optimized `world_from_body` (the input for fixed ones).
    pub keyframes: Vec<Isometry3<f64>>,
    /// Per landmark, the optimized position in `world` (the input for fixed ones).
    pub landmarks: Vec<Vector3<f64>>,
    /// Per observation: at the final estimate, its χ² exceeds its threshold or its
    /// landmark is not in front of the camera (ORB-SLAM erases these from the map).
    pub outliers: Vec<bool>,
    /// The Huber cost `Σ ρ(χ²)` (σ units) of every observation in front of its camera, at
    /// the input.
    pub initial_cost: f64,
    /// The same cost at the output (comparable with `initial_cost`, whatever the rounds).
    pub final_cost: f64,
    /// Levenberg-Marquardt iterations (linearizations), all rounds together.
    pub iterations: usize,
}

/// Why [`bundle_adjust`] did not run.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum BundleError {
    /// The settings are out of range.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// Every keyframe is free: the map's pose is undetermined (gauge freedom).
    #[error("bundle adjustment needs at least one fixed keyframe (gauge), none of {keyframes} is")]
    NoFixedKeyFrame {
        /// Keyframes in the problem.
        keyframes: usize,
    },
    /// An observation names a keyframe the problem does not have.
    #[error("observation {observation} names keyframe {keyframe}, the problem has {keyframes}")]
    UnknownKeyFrame {
        /// The observation.
        observation: usize,
        /// Its keyframe.
        keyframe: usize,
        /// Keyframes in the problem.
        keyframes: usize,
    },
    /// An observation names a landmark the problem does not have.
    #[error("observation {observation} names landmark {landmark}, the problem has {landmarks}")]
    UnknownLandmark {
        /// The observation.
        observation: usize,
        /// Its landmark.
        landmark: usize,
        /// Landmarks in the problem.
        landmarks: usize,
    },
    /// An observation names a camera not passed in.
    #[error("observation {observation} names camera {camera}, {cameras} were given")]
    UnknownCamera {
        /// The observation.
        observation: usize,
        /// Its camera.
        camera: usize,
        /// Cameras given.
        cameras: usize,
    },
    /// An observation's pixel or right-image column is not finite.
    #[error("observation {observation} has a non-finite pixel or right-image column")]
    NonFiniteObservation {
        /// The observation.
        observation: usize,
    },
    /// A stereo observation's baseline is not a positive finite number.
    #[error("observation {observation} is stereo with baseline {baseline_m} m (must be > 0)")]
    BadBaseline {
        /// The observation.
        observation: usize,
        /// Its baseline, m.
        baseline_m: f64,
    },
    /// A keyframe pose is not finite.
    #[error("keyframe {keyframe} has a non-finite pose")]
    NonFiniteKeyFrame {
        /// The keyframe.
        keyframe: usize,
    },
    /// A landmark position is not finite.
    #[error("landmark {landmark} has a non-finite position")]
    NonFiniteLandmark {
        /// The landmark.
        landmark: usize,
    },
    /// A camera's intrinsics or extrinsics are not finite, or a focal length is not
    /// positive.
    #[error("camera {camera} has non-finite or non-positive intrinsics or extrinsics")]
    BadCamera {
        /// The camera.
        camera: usize,
    },
}

/// One observation linearized at an estimate (see the module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct Linearization {
    /// Measured minus predicted, px: `(u, v, u_r)`, the last entry 0 when monocular.
    pub residual: Vector3<f64>,
    /// `∂r/∂δ` for the left pose update `Exp(δ) · body_from_world`, `δ = (ω, v)` (last row
    /// 0 when monocular).
    pub d_pose: Matrix3x6<f64>,
    /// `∂r/∂X` for the landmark in `world` (last row 0 when monocular).
    pub d_point: Matrix3<f64>,
}

/// The residual and Jacobians of `obs` with the keyframe at `body_from_world` and its
/// landmark at `landmark` (world), for `camera`; `None` when the landmark is not in front
/// of the camera.
pub fn linearize(
    camera: &RigCamera,
    body_from_world: &Isometry3<f64>,
    landmark: &Vector3<f64>,
    obs: &BaObservation,
) -> Option<Linearization> {
    let camera_from_body = camera.body_from_camera.inverse();
    let p_b = (body_from_world * Point3::from(*landmark)).coords;
    let p_c = (camera_from_body * Point3::from(p_b)).coords;
    let (residual, d_proj) = residual_and_derivative(camera, &p_c, obs)?;
    let d_pc = d_proj * camera_from_body.rotation.to_rotation_matrix().matrix();
    let mut d_pb = Matrix3x6::zeros();
    d_pb.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(-p_b.cross_matrix()));
    d_pb.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&Matrix3::identity());
    Some(Linearization {
        residual,
        d_pose: -(d_pc * d_pb),
        d_point: -(d_pc * body_from_world.rotation.to_rotation_matrix().matrix()),
    })
}

/// The residual of `obs` for its landmark at `p_c` (camera frame) and the derivative of
/// the prediction, `∂(π(p_c), π_u(p_c) - f_x·b/z)/∂p_c` (third row 0 when monocular);
/// `None` when the landmark is not in front of the camera.
fn residual_and_derivative(
    camera: &RigCamera,
    p_c: &Vector3<f64>,
    obs: &BaObservation,
) -> Option<(Vector3<f64>, Matrix3<f64>)> {
    let predicted = camera.project(p_c)?;
    let z_inv = 1.0 / p_c.z;
    let z_inv2 = z_inv * z_inv;
    let (fx, fy) = (camera.fx, camera.fy);
    let mut d_proj = Matrix3::new(
        fx * z_inv,
        0.0,
        -fx * p_c.x * z_inv2,
        0.0,
        fy * z_inv,
        -fy * p_c.y * z_inv2,
        0.0,
        0.0,
        0.0,
    );
    let r = obs.pixel - predicted;
    let mut residual = Vector3::new(r.x, r.y, 0.0);
    if let Some(ur) = obs.right_x {
        let b = obs.baseline_m;
        residual.z = ur - (predicted.x - fx * b * z_inv);
        // ∂(u - fx·b/z)/∂p_c = (fx/z, 0, -fx·(x - b)/z²).
        d_proj[(2, 0)] = fx * z_inv;
        d_proj[(2, 2)] = -fx * (p_c.x - b) * z_inv2;
    }
    Some((residual, d_proj))
}

/// Huber cost `ρ(χ²)` for a kernel of width `sqrt(threshold)`: `χ²` inside,
/// `2·w·|r| - w²` outside.
fn huber_cost(chi2: f64, threshold: f64) -> f64 {
    if chi2 <= threshold {
        chi2
    } else {
        2.0 * (threshold * chi2).sqrt() - threshold
    }
}

/// The Huber weight `ρ'(χ²)`: 1 inside, `w / |r|` outside.
fn huber_weight(chi2: f64, threshold: f64) -> f64 {
    if chi2 <= threshold {
        1.0
    } else {
        (threshold / chi2).sqrt()
    }
}

/// `Exp(δ) · pose` with the rotation renormalized (no drift over many updates).
fn update_pose(delta: &Vector6<f64>, pose: &Isometry3<f64>) -> Isometry3<f64> {
    let mut p = retract(delta, pose);
    p.rotation = UnitQuaternion::new_normalize(p.rotation.into_inner());
    p
}

/// Marquardt damping of a diagonal entry.
fn damp(d: f64, lambda: f64) -> f64 {
    d + lambda * (d.max(0.0) + DAMPING_FLOOR)
}

/// The estimate the optimizer works on.
#[derive(Clone)]
struct Estimate {
    /// Per keyframe, `body_from_world`.
    poses: Vec<Isometry3<f64>>,
    /// Per keyframe, `body_from_world` as a rotation matrix and a translation.
    frames: Vec<(Matrix3<f64>, Vector3<f64>)>,
    /// Per landmark, `world`.
    points: Vec<Vector3<f64>>,
}

impl Estimate {
    fn new(poses: Vec<Isometry3<f64>>, points: Vec<Vector3<f64>>) -> Estimate {
        Estimate {
            frames: poses.iter().map(matrix_form).collect(),
            poses,
            points,
        }
    }
}

/// An isometry as a rotation matrix and a translation.
fn matrix_form(iso: &Isometry3<f64>) -> (Matrix3<f64>, Vector3<f64>) {
    (
        *iso.rotation.to_rotation_matrix().matrix(),
        iso.translation.vector,
    )
}

/// One observation linearized in the compact form the normal equations are built from.
///
/// With `A = ∂π/∂p_c · R_cb` (2 or 3 rows), `P = [-[p_b]× | I]` and `R = R_bw`, the
/// Jacobians are `Jp = -A·P` and `Jx = -A·R`, so every block of the normal equations
/// follows from `B = Aᵀ·w·A`, `e = Aᵀ·w·r` and `p_b`: `Jpᵀ w Jp = Pᵀ B P`,
/// `-Jpᵀ w r = Pᵀ e`, `Jxᵀ w Jx = Rᵀ B R`, `-Jxᵀ w r = Rᵀ e`, `Jpᵀ w Jx = Pᵀ B R`.
struct Compact {
    /// `Aᵀ·w·A`.
    b: Matrix3<f64>,
    /// `Aᵀ·w·r`.
    e: Vector3<f64>,
    /// The landmark in the body frame.
    p_b: Vector3<f64>,
}

/// `Pᵀ·m` for `P = [-[p]× | I]`: the rows `[p]×·m` over `m`.
fn p_transpose_times(p: &Vector3<f64>, m: &Matrix3<f64>) -> Matrix6x3<f64> {
    let mut out = Matrix6x3::zeros();
    out.fixed_view_mut::<3, 3>(0, 0)
        .copy_from(&(p.cross_matrix() * m));
    out.fixed_view_mut::<3, 3>(3, 0).copy_from(m);
    out
}

/// A used observation of a free landmark by a free keyframe: `Jpᵀ w Jx`.
#[derive(Clone, Copy)]
struct Coupling {
    /// The free keyframe (`usize::MAX`: the slot is unused in this iteration).
    keyframe: usize,
    /// `Jpᵀ w Jx`.
    w: Matrix6x3<f64>,
}

impl Coupling {
    const UNUSED: Coupling = Coupling {
        keyframe: usize::MAX,
        w: Matrix6x3::new(
            0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0,
            0.0,
        ),
    };
}

/// What a free landmark contributes at one linearization.
#[derive(Clone, Copy)]
struct LandmarkBlock {
    /// `Σ Jxᵀ W Jx`.
    v: Matrix3<f64>,
    /// `-Σ Jxᵀ W r`.
    g: Vector3<f64>,
    /// Observations used.
    n_used: usize,
    /// The lowest and highest position ([`Problem::structure`]) of a free keyframe coupled
    /// (`lo > hi`: none).
    span: (usize, usize),
}

/// The normal equations at one linearization.
struct Normal {
    /// Per free keyframe: `Σ Jpᵀ W Jp`.
    u: Vec<Matrix6<f64>>,
    /// Per free keyframe: `-Σ Jpᵀ W r`.
    g_pose: Vec<Vector6<f64>>,
    /// Per free landmark.
    landmarks: Vec<LandmarkBlock>,
    /// Per observation of a free landmark, in [`Problem::by_landmark`] order.
    coupling: Vec<Coupling>,
}

/// A damped step.
struct Step {
    /// Per free keyframe.
    pose: Vec<Vector6<f64>>,
    /// Per free landmark.
    point: Vec<Vector3<f64>>,
}

/// Observations grouped by an item (compressed rows).
struct Groups {
    /// Observation indices, group after group.
    index: Vec<usize>,
    /// Where each group starts in `index` (one more entry at the end).
    start: Vec<usize>,
}

impl Groups {
    /// Groups `items` (in item order, each group in the order of `items`) by `key`
    /// (`None`: left out), `n` groups.
    fn new(
        items: impl Iterator<Item = usize> + Clone,
        key: impl Fn(usize) -> Option<usize>,
        n: usize,
    ) -> Groups {
        let mut start = vec![0usize; n + 1];
        for i in items.clone() {
            if let Some(g) = key(i) {
                start[g + 1] += 1;
            }
        }
        for g in 0..n {
            start[g + 1] += start[g];
        }
        let mut next = start.clone();
        let mut index = vec![0usize; start[n]];
        for i in items {
            if let Some(g) = key(i) {
                index[next[g]] = i;
                next[g] += 1;
            }
        }
        Groups { index, start }
    }

    /// The range of group `g` in `index`.
    fn range(&self, g: usize) -> std::ops::Range<usize> {
        self.start[g]..self.start[g + 1]
    }
}

/// The problem with its fixed parts resolved.
struct Problem<'a> {
    cameras: &'a [RigCamera],
    /// Per camera, `camera_from_body` as a rotation matrix and a translation.
    camera_from_body: Vec<(Matrix3<f64>, Vector3<f64>)>,
    observations: &'a [BaObservation],
    /// Per observation: the level information `scale_factor^(-2·level)`.
    info: Vec<f64>,
    /// Per observation: its χ² threshold.
    threshold: Vec<f64>,
    /// Per keyframe: its index among the free ones.
    free_keyframe: Vec<Option<usize>>,
    /// Per landmark: its index among the free ones.
    free_landmark: Vec<Option<usize>>,
    n_free_keyframes: usize,
    n_free_landmarks: usize,
    /// The observations of each free landmark, by the elimination position of their free
    /// keyframe (fixed keyframes last), then keyframe, then input order.
    by_landmark: Groups,
    /// The observations of each free keyframe, in input order.
    by_keyframe: Groups,
    /// The reduced camera system's block structure over the free keyframes (coupled when
    /// they see a free landmark in common) and its elimination order.
    structure: BlockStructure,
}

impl<'a> Problem<'a> {
    fn new(
        cameras: &'a [RigCamera],
        keyframes: &[BaKeyFrame],
        landmarks: &[BaLandmark],
        observations: &'a [BaObservation],
        cfg: &BundleConfig,
    ) -> Problem<'a> {
        /// Index among the free ones, per item.
        fn free_indices(fixed: impl Iterator<Item = bool>) -> (Vec<Option<usize>>, usize) {
            let mut n = 0;
            let v = fixed
                .map(|f| {
                    (!f).then(|| {
                        n += 1;
                        n - 1
                    })
                })
                .collect();
            (v, n)
        }
        let (free_keyframe, n_free_keyframes) = free_indices(keyframes.iter().map(|k| k.fixed));
        let (free_landmark, n_free_landmarks) = free_indices(landmarks.iter().map(|l| l.fixed));
        let by_keyframe = Groups::new(
            0..observations.len(),
            |i| free_keyframe[observations[i].keyframe],
            n_free_keyframes,
        );
        // By keyframe (every one, fixed or not), then stably by landmark.
        let all_by_keyframe = Groups::new(
            0..observations.len(),
            |i| Some(observations[i].keyframe),
            keyframes.len(),
        );
        let mut by_landmark = Groups::new(
            all_by_keyframe.index.iter().copied(),
            |i| free_landmark[observations[i].landmark],
            n_free_landmarks,
        );
        // Free keyframes coupled through a free landmark: every pair of its observers.
        let mut pairs = Vec::new();
        let mut observers = Vec::new();
        for j in 0..n_free_landmarks {
            observers.clear();
            for &i in &by_landmark.index[by_landmark.range(j)] {
                if let Some(k) = free_keyframe[observations[i].keyframe] {
                    if observers.last() != Some(&k) {
                        observers.push(k);
                    }
                }
            }
            for (b, &kb) in observers.iter().enumerate() {
                pairs.extend(observers[..b].iter().map(|&ka| (ka, kb)));
            }
        }
        pairs.sort_unstable();
        pairs.dedup();
        let structure = BlockStructure::new(n_free_keyframes, pairs);
        // Each landmark's observations by the elimination position of their keyframe
        // (fixed keyframes last; stable), so that the Schur complement walks the columns
        // of the structure in order.
        let key = |i: &usize| {
            free_keyframe[observations[*i].keyframe].map_or(usize::MAX, |k| structure.position(k))
        };
        for j in 0..n_free_landmarks {
            let range = by_landmark.range(j);
            by_landmark.index[range].sort_by_key(key);
        }
        Problem {
            cameras,
            camera_from_body: cameras
                .iter()
                .map(|c| matrix_form(&c.body_from_camera.inverse()))
                .collect(),
            observations,
            info: observations
                .iter()
                .map(|o| cfg.scale_factor.powi(-2 * i32::from(o.level)))
                .collect(),
            threshold: observations
                .iter()
                .map(|o| {
                    if o.right_x.is_some() {
                        cfg.chi2_stereo
                    } else {
                        cfg.chi2_mono
                    }
                })
                .collect(),
            free_keyframe,
            free_landmark,
            n_free_keyframes,
            n_free_landmarks,
            by_landmark,
            by_keyframe,
            structure,
        }
    }

    /// Observation `i`'s landmark in the body frame and in the camera frame.
    fn points_in_frames(&self, est: &Estimate, i: usize) -> (Vector3<f64>, Vector3<f64>) {
        let o = &self.observations[i];
        let (r_bw, t_bw) = &est.frames[o.keyframe];
        let (r_cb, t_cb) = &self.camera_from_body[o.camera];
        let p_b = r_bw * est.points[o.landmark] + t_bw;
        (p_b, r_cb * p_b + t_cb)
    }

    /// χ² of observation `i` (σ units), `None` when its landmark is not in front.
    fn chi2(&self, est: &Estimate, i: usize) -> Option<f64> {
        let o = &self.observations[i];
        let camera = &self.cameras[o.camera];
        let (_, p_c) = self.points_in_frames(est, i);
        let predicted = camera.project(&p_c)?;
        let r = o.pixel - predicted;
        let r_right = o.right_x.map_or(0.0, |ur| {
            ur - (predicted.x - camera.fx * o.baseline_m / p_c.z)
        });
        Some((r.norm_squared() + r_right * r_right) * self.info[i]).filter(|c| c.is_finite())
    }

    /// χ² of every observation (in parallel; `None`: not in front of its camera).
    fn all_chi2(&self, est: &Estimate) -> Vec<Option<f64>> {
        (0..self.observations.len())
            .into_par_iter()
            .map(|i| self.chi2(est, i))
            .collect()
    }

    /// ρ(χ²) of observation `i`: Huber or plain.
    fn rho(&self, chi2: f64, i: usize, robust: bool) -> f64 {
        if robust {
            huber_cost(chi2, self.threshold[i])
        } else {
            chi2
        }
    }

    /// Cost of the observations in `used` at `est`, robust or plain. One whose landmark
    /// is not in front of its camera there counts with its cost at the linearization
    /// point, `at_linearization` (it drops out at the next linearization, as an outlier
    /// would): a step is judged on the others, not thrown away because a landmark
    /// crossed a camera's plane. Summed serially, in order.
    fn cost(
        &self,
        est: &Estimate,
        used: &[bool],
        robust: bool,
        at_linearization: &[Option<f64>],
    ) -> f64 {
        let chi2 = self.all_chi2(est);
        let mut total = 0.0;
        for (i, c) in chi2.iter().enumerate().filter(|(i, _)| used[*i]) {
            if let Some(c) = c.or(at_linearization[i]) {
                total += self.rho(c, i, robust);
            }
        }
        total
    }

    /// The Huber cost of every observation in front of its camera (the reported cost).
    fn reported_cost(&self, chi2: &[Option<f64>]) -> f64 {
        chi2.iter()
            .zip(&self.threshold)
            .filter_map(|(c, t)| c.map(|c| huber_cost(c, *t)))
            .sum()
    }

    /// Observation `i` linearized in the compact form; `None` when its landmark is not in
    /// front of the camera.
    fn compact(&self, est: &Estimate, i: usize, robust: bool) -> Option<Compact> {
        let o = &self.observations[i];
        let camera = &self.cameras[o.camera];
        let (p_b, p_c) = self.points_in_frames(est, i);
        let (res, d_proj) = residual_and_derivative(camera, &p_c, o)?;
        let chi2 = res.norm_squared() * self.info[i];
        if !chi2.is_finite() {
            return None;
        }
        let w = self.info[i]
            * if robust {
                huber_weight(chi2, self.threshold[i])
            } else {
                1.0
            };
        let a = d_proj * self.camera_from_body[o.camera].0;
        let a_t_w = a.transpose() * w;
        Some(Compact {
            b: a_t_w * a,
            e: a_t_w * res,
            p_b,
        })
    }

    /// Linearizes the observations in `used` and builds the normal equations: the
    /// landmark blocks and couplings in parallel over the landmarks, the keyframe blocks in
    /// parallel over the keyframes, each sum in a fixed order. `used` must hold only
    /// observations in front of their camera. `coupling`
    /// is a buffer to fill (the previous iteration's, to spare the allocation).
    fn normal_equations(
        &self,
        est: &Estimate,
        used: &[bool],
        robust: bool,
        mut coupling: Vec<Coupling>,
    ) -> Normal {
        coupling.resize(self.by_landmark.index.len(), Coupling::UNUSED);
        // Split the couplings into each landmark's slots.
        let mut slots: Vec<&mut [Coupling]> = Vec::with_capacity(self.n_free_landmarks);
        let mut rest: &mut [Coupling] = &mut coupling;
        for j in 0..self.n_free_landmarks {
            let (head, tail) = rest.split_at_mut(self.by_landmark.range(j).len());
            slots.push(head);
            rest = tail;
        }
        let landmarks: Vec<LandmarkBlock> = slots
            .into_par_iter()
            .enumerate()
            .map(|(j, slots)| {
                let mut block = LandmarkBlock {
                    v: Matrix3::zeros(),
                    g: Vector3::zeros(),
                    n_used: 0,
                    span: (usize::MAX, 0),
                };
                let range = self.by_landmark.range(j);
                for (slot, &i) in slots.iter_mut().zip(&self.by_landmark.index[range]) {
                    *slot = Coupling::UNUSED;
                    if !used[i] {
                        continue;
                    }
                    let Some(c) = self.compact(est, i, robust) else {
                        continue;
                    };
                    let o = &self.observations[i];
                    let r = &est.frames[o.keyframe].0;
                    let b_r = c.b * r;
                    block.v += r.transpose() * b_r;
                    block.g += r.transpose() * c.e;
                    block.n_used += 1;
                    if let Some(k) = self.free_keyframe[o.keyframe] {
                        *slot = Coupling {
                            keyframe: k,
                            w: p_transpose_times(&c.p_b, &b_r),
                        };
                        let p = self.structure.position(k);
                        block.span = (block.span.0.min(p), block.span.1.max(p));
                    }
                }
                block
            })
            .collect();
        let (u, g_pose): (Vec<Matrix6<f64>>, Vec<Vector6<f64>>) = (0..self.n_free_keyframes)
            .into_par_iter()
            .map(|k| {
                let mut u = Matrix6::zeros();
                let mut g = Vector6::zeros();
                for &i in &self.by_keyframe.index[self.by_keyframe.range(k)] {
                    if !used[i] {
                        continue;
                    }
                    let Some(c) = self.compact(est, i, robust) else {
                        continue;
                    };
                    // Pᵀ B P = [[p]× B (-[p]×), [p]× B; B (-[p]×), B].
                    let px = c.p_b.cross_matrix();
                    let pt_b = p_transpose_times(&c.p_b, &c.b);
                    u.fixed_view_mut::<6, 3>(0, 0).add_assign(&(pt_b * (-px)));
                    u.fixed_view_mut::<6, 3>(0, 3).add_assign(&pt_b);
                    g.fixed_rows_mut::<3>(0).add_assign(&c.p_b.cross(&c.e));
                    g.fixed_rows_mut::<3>(3).add_assign(&c.e);
                }
                (u, g)
            })
            .unzip();
        Normal {
            u,
            g_pose,
            landmarks,
            coupling,
        }
    }

    /// The couplings of free landmark `j` (unused slots included).
    fn coupling<'n>(&self, n: &'n Normal, j: usize) -> &'n [Coupling] {
        &n.coupling[self.by_landmark.range(j)]
    }

    /// The damped step; `None` when the reduced camera system is not positive definite.
    fn solve(&self, n: &Normal, lambda: f64) -> Option<Step> {
        let (nk, nl) = (self.n_free_keyframes, self.n_free_landmarks);
        // Damped landmark blocks, inverted (a landmark that cannot be is held for this
        // step: its observations then constrain the keyframes as if it were fixed).
        let v_inv: Vec<Option<Matrix3<f64>>> = n
            .landmarks
            .par_iter()
            .map(|l| {
                if l.n_used == 0 {
                    return None;
                }
                let mut v = l.v;
                for d in 0..3 {
                    v[(d, d)] = damp(v[(d, d)], lambda);
                }
                v.cholesky()
                    .map(|c| c.inverse())
                    .filter(|m| m.iter().all(|x| x.is_finite()))
            })
            .collect();
        // The reduced camera system S = U - Σ W V⁻¹ Wᵀ in the blocks of the sparse
        // structure (by elimination position), each task owning the diagonal blocks and
        // the columns of a run of positions: every entry is summed in the same order
        // (landmark, then observation) whichever task computes it, so the split (here by
        // the number of threads) does not change a bit.
        let s = &self.structure;
        let mut diag = vec![Matrix6::<f64>::zeros(); nk];
        let mut off = vec![Matrix6::<f64>::zeros(); s.n_blocks()];
        let per_task = nk.div_ceil(2 * rayon::current_num_threads()).max(1);
        let mut tasks = Vec::new();
        let (mut diag_rest, mut off_rest): (&mut [Matrix6<f64>], &mut [Matrix6<f64>]) =
            (&mut diag, &mut off);
        for p0 in (0..nk).step_by(per_task) {
            let p1 = (p0 + per_task).min(nk);
            let slots = s.column(p0).start..s.column(p1 - 1).end;
            let (d, d_tail) = diag_rest.split_at_mut(p1 - p0);
            let (o, o_tail) = off_rest.split_at_mut(slots.len());
            tasks.push((p0..p1, slots.start, d, o));
            diag_rest = d_tail;
            off_rest = o_tail;
        }
        tasks
            .into_par_iter()
            .for_each(|(positions, slot0, diag, off)| {
                self.assemble_columns(n, &v_inv, lambda, positions, slot0, diag, off);
            });
        // b = g - Σ W V⁻¹ g_x, by position.
        let mut b: Vec<Vector6<f64>> = (0..nk).map(|p| n.g_pose[s.variable_at(p)]).collect();
        for (j, inv) in v_inv.iter().enumerate() {
            let Some(inv) = inv else { continue };
            let t = inv * n.landmarks[j].g;
            for c in self.coupling(n, j) {
                if c.keyframe < nk {
                    b[s.position(c.keyframe)] -= c.w * t;
                }
            }
        }
        let mut cholesky = BlockCholesky::new(s);
        if !cholesky.factor(s, &diag, &off) {
            return None;
        }
        cholesky.solve(s, &mut b);
        if !b.iter().all(|v| v.iter().all(|x| x.is_finite())) {
            return None;
        }
        let pose: Vec<Vector6<f64>> = (0..nk).map(|k| b[s.position(k)]).collect();
        let point: Vec<Vector3<f64>> = (0..nl)
            .into_par_iter()
            .map(|j| match v_inv[j] {
                Some(inv) => {
                    let mut rhs = n.landmarks[j].g;
                    for c in self.coupling(n, j) {
                        if c.keyframe < nk {
                            rhs -= c.w.transpose() * pose[c.keyframe];
                        }
                    }
                    inv * rhs
                }
                None => Vector3::zeros(),
            })
            .collect();
        Some(Step { pose, point })
    }

    /// The blocks of the positions `positions` of the damped reduced camera system:
    /// `diag` their diagonal blocks, `off` their columns' off-diagonal blocks (the slots
    /// from `slot0` on), `damped U - Σ W V⁻¹ Wᵀ` summed landmark after landmark.
    #[allow(clippy::too_many_arguments)]
    #[inline(never)]
    fn assemble_columns(
        &self,
        n: &Normal,
        v_inv: &[Option<Matrix3<f64>>],
        lambda: f64,
        positions: std::ops::Range<usize>,
        slot0: usize,
        diag: &mut [Matrix6<f64>],
        off: &mut [Matrix6<f64>],
    ) {
        let s = &self.structure;
        let nk = self.n_free_keyframes;
        let (p0, p1) = (positions.start, positions.end);
        for (p, block) in positions.zip(diag.iter_mut()) {
            let mut u = n.u[s.variable_at(p)];
            for d in 0..6 {
                u[(d, d)] = damp(u[(d, d)], lambda);
            }
            *block = u;
        }
        for (j, inv) in v_inv.iter().enumerate() {
            let Some(inv) = inv else { continue };
            let (lo, hi) = n.landmarks[j].span;
            if lo > hi || hi < p0 || lo >= p1 {
                continue;
            }
            // Every ordered pair (a, b) with p_a ≥ p_b, p_b in this task's positions,
            // adds W_a V⁻¹ W_bᵀ = W_a Y_bᵀ to block (p_a, p_b) (unused slots,
            // usize::MAX, are skipped). The couplings come by increasing position, as the
            // rows of a column: one walk finds every block of column p_b.
            let coupling = self.coupling(n, j);
            for cb in coupling.iter().filter(|c| c.keyframe < nk) {
                let pb = s.position(cb.keyframe);
                if !(p0..p1).contains(&pb) {
                    continue;
                }
                let yb = cb.w * inv;
                let column = s.column(pb);
                let rows = s.column_rows(pb);
                let mut cursor = 0;
                for ca in coupling.iter().filter(|c| c.keyframe < nk) {
                    let pa = s.position(ca.keyframe);
                    if pa == pb {
                        sub_product(&mut diag[pb - p0], &ca.w, &yb);
                    } else if pa > pb {
                        while rows[cursor] < pa {
                            cursor += 1;
                        }
                        sub_product(&mut off[column.start + cursor - slot0], &ca.w, &yb);
                    }
                }
            }
        }
    }

    /// Up to `max_iterations` Levenberg-Marquardt iterations over the `active`
    /// observations, robust or plain, from `est`; returns the iterations run. A step is
    /// kept only if it lowers the cost; `λ` follows Nielsen's rule (see the module docs).
    /// Stops when no step in [`LAMBDA_TRIES`]
    /// lowers the cost or a kept one lowers it by less than
    /// [`BundleConfig::min_relative_decrease`] (plain: at least
    /// [`PLAIN_MIN_RELATIVE_DECREASE`]).
    fn levenberg_marquardt(
        &self,
        est: &mut Estimate,
        active: &[bool],
        robust: bool,
        max_iterations: usize,
        cfg: &BundleConfig,
    ) -> usize {
        let mut lambda = cfg.initial_lambda;
        let mut nu = 2.0;
        let mut spare = Vec::new();
        // The plain pass only brings the map near: the robust round refines it.
        let min_relative_decrease = if robust {
            cfg.min_relative_decrease
        } else {
            cfg.min_relative_decrease.max(PLAIN_MIN_RELATIVE_DECREASE)
        };
        for iteration in 0..max_iterations {
            // Linearize (the observations that went behind their camera drop out of the
            // iteration, and the cost is over the rest).
            let chi2 = self.all_chi2(est);
            let used: Vec<bool> = active
                .iter()
                .zip(&chi2)
                .map(|(a, c)| *a && c.is_some())
                .collect();
            let current = self.cost(est, &used, robust, &chi2);
            let normal = self.normal_equations(est, &used, robust, spare);
            let mut kept = None;
            for _ in 0..LAMBDA_TRIES {
                if let Some(step) = self.solve(&normal, lambda) {
                    let candidate = self.apply(est, &step);
                    let c = self.cost(&candidate, &used, robust, &chi2);
                    if c.is_finite() && c < current {
                        // Nielsen's update from the gain ratio ρ (actual over predicted
                        // decrease): a step the model predicted well lets λ fall (at
                        // most 3×), a poor one raises it.
                        let predicted = self.predicted_decrease(&normal, &step, lambda);
                        let rho = (current - c) / predicted.max(f64::MIN_POSITIVE);
                        let factor = (1.0 - (2.0 * rho.min(1.0) - 1.0).powi(3)).max(1.0 / 3.0);
                        lambda = (lambda * factor).max(1e-12);
                        nu = 2.0;
                        kept = Some((candidate, c));
                        break;
                    }
                }
                lambda *= nu;
                nu *= 2.0;
            }
            spare = normal.coupling;
            let Some((candidate, c)) = kept else {
                return iteration + 1;
            };
            *est = candidate;
            if current - c <= min_relative_decrease * current {
                return iteration + 1;
            }
        }
        max_iterations
    }

    /// The decrease of the (weighted) cost the linear model predicts for `step`, the
    /// solution of `(H + λD) δ = g`: `2δᵀg - δᵀHδ = δᵀg + λ δᵀDδ`.
    fn predicted_decrease(&self, n: &Normal, step: &Step, lambda: f64) -> f64 {
        let mut total = 0.0;
        for ((d, u), g) in step.pose.iter().zip(&n.u).zip(&n.g_pose) {
            for i in 0..6 {
                total += d[i] * (g[i] + lambda * (u[(i, i)].max(0.0) + DAMPING_FLOOR) * d[i]);
            }
        }
        for (d, l) in step.point.iter().zip(&n.landmarks) {
            for i in 0..3 {
                total += d[i] * (l.g[i] + lambda * (l.v[(i, i)].max(0.0) + DAMPING_FLOOR) * d[i]);
            }
        }
        total
    }

    /// `est` moved by `step`.
    fn apply(&self, est: &Estimate, step: &Step) -> Estimate {
        let poses = est
            .poses
            .iter()
            .zip(&self.free_keyframe)
            .map(|(pose, free)| free.map_or(*pose, |k| update_pose(&step.pose[k], pose)))
            .collect();
        let points = est
            .points
            .iter()
            .zip(&self.free_landmark)
            .map(|(point, free)| free.map_or(*point, |j| point + step.point[j]))
            .collect();
        Estimate::new(poses, points)
    }
}

/// `block -= a · bᵀ`.
fn sub_product(block: &mut Matrix6<f64>, a: &Matrix6x3<f64>, b: &Matrix6x3<f64>) {
    let out = &mut block.data.0;
    let a = &a.data.0;
    let b = &b.data.0;
    for (c, column) in out.iter_mut().enumerate() {
        let (b0, b1, b2) = (b[0][c], b[1][c], b[2][c]);
        for (r, x) in column.iter_mut().enumerate() {
            *x -= a[0][r] * b0 + a[1][r] * b1 + a[2][r] * b2;
        }
    }
}

/// Checks the indices and that every number is finite.
fn validate_input(
    cameras: &[RigCamera],
    keyframes: &[BaKeyFrame],
    landmarks: &[BaLandmark],
    observations: &[BaObservation],
) -> Result<(), BundleError> {
    for (camera, c) in cameras.iter().enumerate() {
        let iso = &c.body_from_camera;
        let finite = [c.fx, c.fy, c.cx, c.cy].iter().all(|x| x.is_finite())
            && iso.translation.vector.iter().all(|x| x.is_finite())
            && iso.rotation.coords.iter().all(|x| x.is_finite());
        if !finite || c.fx <= 0.0 || c.fy <= 0.0 {
            return Err(BundleError::BadCamera { camera });
        }
    }
    for (keyframe, k) in keyframes.iter().enumerate() {
        let iso = &k.world_from_body;
        if !(iso.translation.vector.iter().all(|x| x.is_finite())
            && iso.rotation.coords.iter().all(|x| x.is_finite()))
        {
            return Err(BundleError::NonFiniteKeyFrame { keyframe });
        }
    }
    for (landmark, l) in landmarks.iter().enumerate() {
        if !l.position.iter().all(|x| x.is_finite()) {
            return Err(BundleError::NonFiniteLandmark { landmark });
        }
    }
    if !keyframes.iter().any(|k| k.fixed) {
        return Err(BundleError::NoFixedKeyFrame {
            keyframes: keyframes.len(),
        });
    }
    for (observation, o) in observations.iter().enumerate() {
        if o.keyframe >= keyframes.len() {
            return Err(BundleError::UnknownKeyFrame {
                observation,
                keyframe: o.keyframe,
                keyframes: keyframes.len(),
            });
        }
        if o.landmark >= landmarks.len() {
            return Err(BundleError::UnknownLandmark {
                observation,
                landmark: o.landmark,
                landmarks: landmarks.len(),
            });
        }
        if o.camera >= cameras.len() {
            return Err(BundleError::UnknownCamera {
                observation,
                camera: o.camera,
                cameras: cameras.len(),
            });
        }
        if !(o.pixel.iter().all(|x| x.is_finite()) && o.right_x.is_none_or(f64::is_finite)) {
            return Err(BundleError::NonFiniteObservation { observation });
        }
        if o.right_x.is_some() && !(o.baseline_m.is_finite() && o.baseline_m > 0.0) {
            return Err(BundleError::BadBaseline {
                observation,
                baseline_m: o.baseline_m,
            });
        }
    }
    Ok(())
}

/// Bundle adjustment of the free `keyframes` and `landmarks` over `observations` (eqs.
/// 4-5; see the module documentation), from their given values.
///
/// `cameras` are indexed by [`BaObservation::camera`]. At least one keyframe must be fixed
/// (the gauge); with monocular observations only, fix a second one (or some landmarks) to
/// hold the scale. Fixed keyframes and landmarks come back unchanged. The input is checked
/// first: an index out of range, a non-finite number or a non-positive stereo baseline is
/// a [`BundleError`] naming the offender.
pub fn bundle_adjust(
    cameras: &[RigCamera],
    keyframes: &[BaKeyFrame],
    landmarks: &[BaLandmark],
    observations: &[BaObservation],
    cfg: &BundleConfig,
) -> Result<BundleResult, BundleError> {
    cfg.validate()?;
    validate_input(cameras, keyframes, landmarks, observations)?;
    let problem = Problem::new(cameras, keyframes, landmarks, observations, cfg);
    let mut est = Estimate::new(
        keyframes
            .iter()
            .map(|k| k.world_from_body.inverse())
            .collect(),
        landmarks.iter().map(|l| l.position).collect(),
    );
    let chi2 = problem.all_chi2(&est);
    let initial_cost = problem.reported_cost(&chi2);
    // Observations taking part: first every one whose landmark is in front.
    let mut active: Vec<bool> = chi2.iter().map(Option::is_some).collect();
    let mut iterations = 0;
    if cfg.plain_iterations > 0 {
        iterations +=
            problem.levenberg_marquardt(&mut est, &active, false, cfg.plain_iterations, cfg);
    }
    for round in 0..cfg.rounds {
        let last = round + 1 == cfg.rounds;
        let robust = !last || cfg.robust_final_round;
        iterations +=
            problem.levenberg_marquardt(&mut est, &active, robust, cfg.iterations_per_round, cfg);
        if !last {
            // Classify every observation (one set aside earlier may come back).
            let chi2 = problem.all_chi2(&est);
            for ((a, c), t) in active.iter_mut().zip(&chi2).zip(&problem.threshold) {
                *a = c.is_some_and(|c| c <= *t);
            }
        }
    }
    let chi2 = problem.all_chi2(&est);
    let outliers = chi2
        .iter()
        .zip(&problem.threshold)
        .map(|(c, t)| c.is_none_or(|c| c > *t))
        .collect();
    let final_cost = problem.reported_cost(&chi2);
    Ok(BundleResult {
        keyframes: keyframes
            .iter()
            .zip(&est.poses)
            .map(|(k, p)| {
                if k.fixed {
                    k.world_from_body
                } else {
                    p.inverse()
                }
            })
            .collect(),
        landmarks: est.points,
        outliers,
        initial_cost,
        final_cost,
        iterations,
    })
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, Translation3};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    const WIDTH: f64 = 752.0;
    const HEIGHT: f64 = 480.0;
    const BASELINE_M: f64 = 0.12;
    /// Nearer than this a landmark is matched in the right image too.
    const STEREO_DEPTH_M: f64 = 5.0;

    fn rig() -> Vec<RigCamera> {
        crate::slam::bench::synthetic_rig()
    }

    /// `n` rig poses along x, `spacing` m apart, with a slight sway in y, yaw and tilt.
    fn row_poses(n: usize, spacing: f64) -> Vec<Isometry3<f64>> {
        (0..n)
            .map(|k| {
                let k = k as f64;
                Isometry3::from_parts(
                    Translation3::new(spacing * k, 0.05 * (0.7 * k).sin(), 0.01 * k.cos()),
                    UnitQuaternion::from_euler_angles(
                        0.01 * (0.3 * k).sin(),
                        0.01 * (0.4 * k).cos(),
                        0.03 * (0.5 * k).sin(),
                    ),
                )
            })
            .collect()
    }

    /// `n` landmarks on two vine-row walls at y = ±1.2 m (±0.15 m), 0.2-1.8 m high,
    /// `x0..x1` along the row.
    fn walls(n: usize, x0: f64, x1: f64, rng: &mut ChaCha8Rng) -> Vec<Vector3<f64>> {
        (0..n)
            .map(|i| {
                let side = if i % 2 == 0 { 1.0 } else { -1.0 };
                Vector3::new(
                    rng.random_range(x0..x1),
                    side * (1.2 + rng.random_range(-0.15..0.15)),
                    rng.random_range(0.2..1.8),
                )
            })
            .collect()
    }

    /// Every landmark seen by every camera of every pose where it projects into the image
    /// 0.5 to `max_depth` m deep, at a random level 0-3, stereo below 5 m, with `noise_px`
    /// of Gaussian noise (times the level's σ).
    fn observe(
        poses: &[Isometry3<f64>],
        points: &[Vector3<f64>],
        max_depth: f64,
        noise_px: f64,
        rng: &mut ChaCha8Rng,
    ) -> Vec<BaObservation> {
        let rig = rig();
        let noise = Normal::new(0.0, noise_px.max(1e-300)).unwrap();
        let mut out = Vec::new();
        for (keyframe, pose) in poses.iter().enumerate() {
            for (camera, cam) in rig.iter().enumerate() {
                let camera_from_world = (pose * cam.body_from_camera).inverse();
                for (landmark, x) in points.iter().enumerate() {
                    let p_c = (camera_from_world * Point3::from(*x)).coords;
                    if !(0.5..max_depth).contains(&p_c.z) {
                        continue;
                    }
                    let px = cam.project(&p_c).unwrap();
                    if !(0.0..WIDTH).contains(&px.x) || !(0.0..HEIGHT).contains(&px.y) {
                        continue;
                    }
                    let level: u8 = rng.random_range(0..4);
                    let sigma = 1.2_f64.powi(i32::from(level));
                    let mut n = || noise.sample(rng) * sigma * f64::from(u8::from(noise_px > 0.0));
                    let pixel = px + Vector2::new(n(), n());
                    let right_x =
                        (p_c.z < STEREO_DEPTH_M).then(|| px.x - cam.fx * BASELINE_M / p_c.z + n());
                    out.push(BaObservation {
                        keyframe,
                        landmark,
                        camera,
                        pixel,
                        level,
                        right_x,
                        baseline_m: BASELINE_M,
                    });
                }
            }
        }
        out
    }

    /// A random left update of about `rot` rad and `trans` m per axis.
    fn random_delta(rng: &mut ChaCha8Rng, rot: f64, trans: f64) -> Vector6<f64> {
        let mut d = Vector6::zeros();
        for k in 0..6 {
            let s = if k < 3 { rot } else { trans };
            d[k] = s * rng.random_range(-1.0..1.0);
        }
        d
    }

    /// Position (m) and rotation (°) difference of two poses.
    fn pose_error(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
        let d = a.inverse() * b;
        (
            (a.translation.vector - b.translation.vector).norm(),
            d.rotation.angle().to_degrees(),
        )
    }

    /// Largest position and rotation errors over the keyframes.
    fn max_errors(est: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> (f64, f64) {
        est.iter()
            .zip(truth)
            .map(|(e, t)| pose_error(e, t))
            .fold((0.0, 0.0), |(a, b), (t, r)| {
                (f64::max(a, t), f64::max(b, r))
            })
    }

    /// RMS position and rotation errors over the free keyframes (the first two are fixed).
    fn rms_errors(est: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> (f64, f64) {
        let e: Vec<(f64, f64)> = est
            .iter()
            .zip(truth)
            .skip(2)
            .map(|(e, t)| pose_error(e, t))
            .collect();
        let n = e.len() as f64;
        (
            (e.iter().map(|x| x.0 * x.0).sum::<f64>() / n).sqrt(),
            (e.iter().map(|x| x.1 * x.1).sum::<f64>() / n).sqrt(),
        )
    }

    #[test]
    fn the_jacobians_match_numeric_differentiation() {
        let rig = rig();
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let poses = row_poses(3, 0.6);
        let points = walls(120, -6.0, 9.0, &mut rng);
        let obs = observe(&poses, &points, 12.0, 1.0, &mut rng);
        let n_stereo = obs.iter().filter(|o| o.right_x.is_some()).count();
        assert!(
            n_stereo >= 20 && obs.len() - n_stereo >= 20,
            "{n_stereo} of {}",
            obs.len()
        );
        // Away from the truth, so the residuals are not zero.
        let body_from_world: Vec<Isometry3<f64>> = poses
            .iter()
            .map(|p| retract(&random_delta(&mut rng, 0.01, 0.03), &p.inverse()))
            .collect();
        let h = 1e-6;
        let r_of = |o: &BaObservation, pose: &Isometry3<f64>, x: &Vector3<f64>| {
            linearize(&rig[o.camera], pose, x, o).unwrap().residual
        };
        for o in &obs {
            let pose = &body_from_world[o.keyframe];
            let x = points[o.landmark];
            let lin = linearize(&rig[o.camera], pose, &x, o).unwrap();
            let dof = o.dof();
            for k in 0..6 {
                let mut d = Vector6::zeros();
                d[k] = h;
                let plus = r_of(o, &retract(&d, pose), &x);
                d[k] = -h;
                let minus = r_of(o, &retract(&d, pose), &x);
                let numeric = (plus - minus) / (2.0 * h);
                let analytic = lin.d_pose.column(k);
                assert!(
                    (numeric - analytic).norm() < 1e-4 * (1.0 + analytic.norm()),
                    "pose column {k} (dof {dof}): numeric {numeric:?} vs analytic {analytic:?}"
                );
            }
            for k in 0..3 {
                let mut d = Vector3::zeros();
                d[k] = h;
                let numeric = (r_of(o, pose, &(x + d)) - r_of(o, pose, &(x - d))) / (2.0 * h);
                let analytic = lin.d_point.column(k);
                assert!(
                    (numeric - analytic).norm() < 1e-4 * (1.0 + analytic.norm()),
                    "point column {k} (dof {dof}): numeric {numeric:?} vs analytic {analytic:?}"
                );
            }
            if dof == 2 {
                assert_eq!(lin.residual.z, 0.0);
                assert_eq!(lin.d_pose.row(2).norm() + lin.d_point.row(2).norm(), 0.0);
            }
        }
    }

    #[test]
    fn the_compact_normal_blocks_match_the_jacobians() {
        // The optimizer builds the normal equations from B = Aᵀ w A, e = Aᵀ w r and p_b;
        // they must equal the products of the Jacobians that were checked numerically.
        let p = local_problem(1.0, 9);
        let rig = rig();
        let cfg = BundleConfig::default();
        let problem = Problem::new(&rig, &p.keyframes, &p.landmarks, &p.obs, &cfg);
        let est = Estimate::new(
            p.keyframes
                .iter()
                .map(|k| k.world_from_body.inverse())
                .collect(),
            p.landmarks.iter().map(|l| l.position).collect(),
        );
        for (i, o) in p.obs.iter().enumerate().step_by(7) {
            let c = problem.compact(&est, i, false).unwrap();
            let lin = linearize(
                &rig[o.camera],
                &est.poses[o.keyframe],
                &est.points[o.landmark],
                o,
            )
            .unwrap();
            let w = problem.info[i];
            let r = est.frames[o.keyframe].0;
            let px = c.p_b.cross_matrix();
            let pt_b = p_transpose_times(&c.p_b, &c.b);
            let mut u = Matrix6::zeros();
            u.fixed_view_mut::<6, 3>(0, 0).copy_from(&(pt_b * (-px)));
            u.fixed_view_mut::<6, 3>(0, 3).copy_from(&pt_b);
            let pairs: [(DMatrix<f64>, DMatrix<f64>); 5] = [
                (
                    DMatrix::from_column_slice(6, 6, u.as_slice()),
                    DMatrix::from_column_slice(
                        6,
                        6,
                        (lin.d_pose.transpose() * w * lin.d_pose).as_slice(),
                    ),
                ),
                (
                    DMatrix::from_column_slice(3, 3, (r.transpose() * c.b * r).as_slice()),
                    DMatrix::from_column_slice(
                        3,
                        3,
                        (lin.d_point.transpose() * w * lin.d_point).as_slice(),
                    ),
                ),
                (
                    DMatrix::from_column_slice(
                        6,
                        3,
                        p_transpose_times(&c.p_b, &(c.b * r)).as_slice(),
                    ),
                    DMatrix::from_column_slice(
                        6,
                        3,
                        (lin.d_pose.transpose() * w * lin.d_point).as_slice(),
                    ),
                ),
                (
                    DMatrix::from_column_slice(
                        6,
                        1,
                        Vector6::new(
                            c.p_b.cross(&c.e).x,
                            c.p_b.cross(&c.e).y,
                            c.p_b.cross(&c.e).z,
                            c.e.x,
                            c.e.y,
                            c.e.z,
                        )
                        .as_slice(),
                    ),
                    DMatrix::from_column_slice(
                        6,
                        1,
                        (-(lin.d_pose.transpose() * w * lin.residual)).as_slice(),
                    ),
                ),
                (
                    DMatrix::from_column_slice(3, 1, (r.transpose() * c.e).as_slice()),
                    DMatrix::from_column_slice(
                        3,
                        1,
                        (-(lin.d_point.transpose() * w * lin.residual)).as_slice(),
                    ),
                ),
            ];
            for (k, (compact, jacobian)) in pairs.iter().enumerate() {
                assert!(
                    (compact - jacobian).norm() <= 1e-9 * (1.0 + jacobian.norm()),
                    "observation {i} block {k}: {compact} vs {jacobian}"
                );
            }
        }
    }

    #[test]
    fn two_cameras_of_one_keyframe_seeing_one_landmark() {
        // Every observation twice, through a copy of its camera: each keyframe then sees
        // each of its landmarks twice (the same-keyframe pairs of the Schur complement).
        // Doubling every term leaves the minimizer where it was.
        let p = local_problem(0.5, 10);
        let mut rig2 = rig();
        rig2.extend(rig());
        let mut obs2 = p.obs.clone();
        obs2.extend(p.obs.iter().map(|o| BaObservation {
            camera: o.camera + 2,
            ..o.clone()
        }));
        let cfg = BundleConfig::local();
        let once = bundle_adjust(&rig(), &p.keyframes, &p.landmarks, &p.obs, &cfg).unwrap();
        let twice = bundle_adjust(&rig2, &p.keyframes, &p.landmarks, &obs2, &cfg).unwrap();
        let (t, r) = max_errors(&once.keyframes, &twice.keyframes);
        assert!(t < 1e-9 && r < 1e-7, "{t} m, {r}°");
        assert_eq!(&twice.outliers[..p.obs.len()], &once.outliers[..]);
        assert_eq!(&twice.outliers[p.obs.len()..], &once.outliers[..]);
    }

    /// A local-BA problem: 8 keyframes 0.5 m apart, 300 landmarks on the walls, the first
    /// two keyframes fixed, the others nudged by up to 1° and 3 cm per axis and every
    /// landmark by up to 3 cm per axis.
    struct LocalProblem {
        truth: Vec<Isometry3<f64>>,
        points: Vec<Vector3<f64>>,
        keyframes: Vec<BaKeyFrame>,
        landmarks: Vec<BaLandmark>,
        obs: Vec<BaObservation>,
    }

    fn local_problem(noise_px: f64, seed: u64) -> LocalProblem {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let truth = row_poses(8, 0.5);
        let points = walls(300, -8.0, 12.0, &mut rng);
        let obs = observe(&truth, &points, 10.0, noise_px, &mut rng);
        let keyframes = truth
            .iter()
            .enumerate()
            .map(|(k, t)| BaKeyFrame {
                world_from_body: if k < 2 {
                    *t
                } else {
                    retract(&random_delta(&mut rng, 1f64.to_radians(), 0.03), t)
                },
                fixed: k < 2,
            })
            .collect();
        let landmarks = points
            .iter()
            .map(|p| BaLandmark {
                position: p + Vector3::new(
                    rng.random_range(-0.03..0.03),
                    rng.random_range(-0.03..0.03),
                    rng.random_range(-0.03..0.03),
                ),
                fixed: false,
            })
            .collect();
        LocalProblem {
            truth,
            points,
            keyframes,
            landmarks,
            obs,
        }
    }

    fn run(p: &LocalProblem, cfg: &BundleConfig) -> BundleResult {
        bundle_adjust(&rig(), &p.keyframes, &p.landmarks, &p.obs, cfg).unwrap()
    }

    fn initial(p: &LocalProblem) -> Vec<Isometry3<f64>> {
        p.keyframes.iter().map(|k| k.world_from_body).collect()
    }

    fn initial_errors(p: &LocalProblem) -> (f64, f64) {
        max_errors(&initial(p), &p.truth)
    }

    /// The problem started at the true poses and landmarks.
    fn start_at_truth(p: &LocalProblem) -> LocalProblem {
        LocalProblem {
            truth: p.truth.clone(),
            points: p.points.clone(),
            keyframes: p
                .truth
                .iter()
                .zip(&p.keyframes)
                .map(|(t, k)| BaKeyFrame {
                    world_from_body: *t,
                    fixed: k.fixed,
                })
                .collect(),
            landmarks: p
                .points
                .iter()
                .map(|x| BaLandmark {
                    position: *x,
                    fixed: false,
                })
                .collect(),
            obs: p.obs.clone(),
        }
    }

    #[test]
    fn local_ba_recovers_exact_poses_and_landmarks() {
        let p = local_problem(0.0, 2);
        let (t0, r0) = initial_errors(&p);
        let res = run(&p, &BundleConfig::local());
        let (t, r) = max_errors(&res.keyframes, &p.truth);
        let n_stereo = p.obs.iter().filter(|o| o.right_x.is_some()).count();
        println!(
            "local BA, exact pixels: {} observations ({n_stereo} stereo), {} iterations; \
             worst pose {t0:.4} m {r0:.3}° → {t:.2e} m {r:.2e}°, cost {:.3e} → {:.3e}",
            p.obs.len(),
            res.iterations,
            res.initial_cost,
            res.final_cost
        );
        assert!(t < 1e-3 && r < 0.01, "{t} m, {r}°");
        assert!(res.final_cost < 1e-6 * res.initial_cost);
        assert!(res.outliers.iter().all(|o| !o));
        // Fixed keyframes are returned as given.
        assert_eq!(res.keyframes[0], p.keyframes[0].world_from_body);
        assert_eq!(res.keyframes[1], p.keyframes[1].world_from_body);
        // Landmarks seen twice or more are back at the truth.
        let mut seen = vec![0usize; p.points.len()];
        p.obs.iter().for_each(|o| seen[o.landmark] += 1);
        for (j, (est, truth)) in res.landmarks.iter().zip(&p.points).enumerate() {
            assert!(est.iter().all(|x| x.is_finite()));
            if seen[j] >= 2 {
                assert!(
                    (est - truth).norm() < 1e-3,
                    "landmark {j}: {}",
                    (est - truth).norm()
                );
            } else if seen[j] == 0 {
                assert_eq!(*est, p.landmarks[j].position, "an unseen landmark stays");
            }
        }
    }

    #[test]
    fn local_ba_reduces_the_error_with_noisy_pixels() {
        let p = local_problem(0.5, 3);
        let (t0, r0) = initial_errors(&p);
        let rms0 = rms_errors(&initial(&p), &p.truth);
        let res = run(&p, &BundleConfig::local());
        let (t, r) = max_errors(&res.keyframes, &p.truth);
        let rms = rms_errors(&res.keyframes, &p.truth);
        let flagged = res.outliers.iter().filter(|o| **o).count();
        // The optimum the noise allows: the same problem started at the truth.
        let from_truth = run(&start_at_truth(&p), &BundleConfig::local());
        let (dt, dr) = max_errors(&res.keyframes, &from_truth.keyframes);
        println!(
            "local BA, 0.5 px noise: {} iterations; worst pose {t0:.4} m {r0:.3}° → {t:.2e} m \
             {r:.2e}° ({:.0}× / {:.0}×), RMS {:.4} m {:.3}° → {:.2e} m {:.2e}° ({:.0}× / \
             {:.0}×), {dt:.1e} m {dr:.1e}° from the optimum started at the truth, {flagged} \
             of {} flagged",
            res.iterations,
            t0 / t,
            r0 / r,
            rms0.0,
            rms0.1,
            rms.0,
            rms.1,
            rms0.0 / rms.0,
            rms0.1 / rms.1,
            p.obs.len()
        );
        // The perturbation is gone: what is left is the noise's (the optimum from the
        // truth), several times smaller in position, tens of times in rotation.
        assert!(dt < 1e-6 && dr < 1e-5, "{dt} m, {dr}° from the optimum");
        assert!(t0 / t > 5.0 && r0 / r > 20.0, "{t} m, {r}°");
        assert!(rms0.0 / rms.0 > 8.0 && rms0.1 / rms.1 > 40.0, "{rms:?}");
        // 0.5 px of noise is half the σ the weights assume: hardly any χ² above 5.99.
        assert!(flagged < p.obs.len() / 10, "{flagged}");
    }

    #[test]
    fn local_ba_flags_gross_outliers() {
        let mut p = local_problem(0.5, 4);
        let mut rng = ChaCha8Rng::seed_from_u64(40);
        // A tenth of the observations 20-80 px wrong, among those of landmarks seen at
        // least 4 times, twice in stereo: the others pin the landmark. (A landmark seen
        // monocularly only from nearly the same direction can slide along its ray until a
        // wrong observation fits: no kernel tells which is wrong then.)
        let mut seen = vec![(0usize, 0usize); p.points.len()];
        for o in &p.obs {
            seen[o.landmark].0 += 1;
            seen[o.landmark].1 += usize::from(o.right_x.is_some());
        }
        let mut wrong = vec![false; p.obs.len()];
        let mut n_wrong = 0;
        for (i, o) in p.obs.iter_mut().enumerate() {
            let (n, n_stereo) = seen[o.landmark];
            if n >= 4 && n_stereo >= 2 && rng.random_bool(0.2) && n_wrong * 10 < wrong.len() {
                let angle: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                let shift = Vector2::new(angle.cos(), angle.sin()) * rng.random_range(20.0..80.0);
                o.pixel += shift;
                if let Some(ur) = o.right_x.as_mut() {
                    *ur += shift.x;
                }
                wrong[i] = true;
                n_wrong += 1;
            }
        }
        let res = run(&p, &BundleConfig::local());
        // The reference: plain BA over the right observations only, from the truth.
        let mut oracle = start_at_truth(&p);
        oracle.obs = p
            .obs
            .iter()
            .zip(&wrong)
            .filter(|(_, w)| !**w)
            .map(|(o, _)| o.clone())
            .collect();
        let reference = run(
            &oracle,
            &BundleConfig {
                rounds: 1,
                iterations_per_round: 50,
                ..BundleConfig::local()
            },
        );
        let (t, r) = max_errors(&res.keyframes, &reference.keyframes);
        let missed = wrong
            .iter()
            .zip(&res.outliers)
            .filter(|(w, o)| **w && !**o)
            .count();
        let right = wrong.iter().filter(|w| !**w).count();
        let kept = wrong
            .iter()
            .zip(&res.outliers)
            .filter(|(w, o)| !**w && !**o)
            .count();
        println!(
            "local BA, {n_wrong} gross outliers in {}: {} iterations, worst pose {t:.2e} m \
             {r:.2e}° from BA over the right ones alone, {missed} missed, {kept} of {right} \
             right ones kept",
            p.obs.len(),
            res.iterations
        );
        assert!(n_wrong * 100 >= 9 * p.obs.len(), "{n_wrong}");
        assert_eq!(missed, 0);
        assert!(kept as f64 > 0.9 * right as f64, "{kept} of {right}");
        // As good as BA over the right observations alone (those it also rejected for
        // noise make the small difference).
        assert!(t < 1e-3 && r < 0.01, "{t} m, {r}°");
        // Without the robust round, they pull the poses away.
        let plain = run(
            &p,
            &BundleConfig {
                rounds: 1,
                ..BundleConfig::local()
            },
        );
        let (t_plain, _) = max_errors(&plain.keyframes, &reference.keyframes);
        assert!(t_plain > 3.0 * t.max(1e-3), "{t_plain} m");
    }

    /// A row of `n` keyframes over 20 m seen drifted as a visual odometry leaves it, with
    /// the loop closure: the truth, the drifted poses, and the problem with the first and
    /// last keyframes fixed at their true poses.
    struct DriftProblem {
        truth: Vec<Isometry3<f64>>,
        drifted: Vec<Isometry3<f64>>,
        keyframes: Vec<BaKeyFrame>,
        landmarks: Vec<BaLandmark>,
        obs: Vec<BaObservation>,
    }

    fn drift_problem(n: usize, seed: u64) -> DriftProblem {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let truth = row_poses(n, 20.0 / (n - 1) as f64);
        let points = walls(900, -8.0, 28.0, &mut rng);
        let obs = observe(&truth, &points, 8.0, 0.5, &mut rng);
        // Odometry drift: 0.2°/m of heading, 0.05°/m of pitch, 1 % long and 1 cm/m lateral
        // translation, accumulated along the row.
        let mut drifted = vec![truth[0]];
        for k in 1..n {
            let step = truth[k - 1].inverse() * truth[k];
            let len = step.translation.vector.norm();
            let mut bad = step;
            bad.translation.vector =
                step.translation.vector * 1.01 + Vector3::new(0.0, 0.01 * len, 0.0);
            let turn = UnitQuaternion::from_euler_angles(
                0.0,
                0.05f64.to_radians() * len,
                0.2f64.to_radians() * len,
            );
            let next = drifted[k - 1] * bad * Isometry3::from_parts(Translation3::identity(), turn);
            drifted.push(next);
        }
        // Each landmark where the drifted keyframe that first saw it put it.
        let mut first = vec![None; points.len()];
        for o in &obs {
            first[o.landmark].get_or_insert(o.keyframe);
        }
        let landmarks = points
            .iter()
            .zip(&first)
            .map(|(x, k)| BaLandmark {
                position: k.map_or(*x, |k| {
                    (drifted[k] * truth[k].inverse() * Point3::from(*x)).coords
                }),
                fixed: false,
            })
            .collect();
        // The loop closure: first and last keyframes at their true poses.
        let keyframes = (0..n)
            .map(|k| {
                let fixed = k == 0 || k == n - 1;
                BaKeyFrame {
                    world_from_body: if fixed { truth[k] } else { drifted[k] },
                    fixed,
                }
            })
            .collect();
        DriftProblem {
            truth,
            drifted,
            keyframes,
            landmarks,
            obs,
        }
    }

    /// RMS position error of the keyframes between the two fixed ends, m.
    fn middle_rms(poses: &[Isometry3<f64>], truth: &[Isometry3<f64>]) -> f64 {
        let n = truth.len();
        let s: f64 = (1..n - 1)
            .map(|k| (poses[k].translation.vector - truth[k].translation.vector).norm_squared())
            .sum();
        (s / (n - 2) as f64).sqrt()
    }

    #[test]
    fn global_ba_with_the_loop_ends_fixed_corrects_drift() {
        let n = 30;
        let p = drift_problem(n, 5);
        let before = middle_rms(&p.drifted, &p.truth);
        let end_drift = pose_error(&p.drifted[n - 1], &p.truth[n - 1]);
        assert!(before > 0.1, "the drift is too small to test: {before} m");
        let run = |obs: &[BaObservation], cfg: &BundleConfig| {
            let t0 = std::time::Instant::now();
            let res = bundle_adjust(&rig(), &p.keyframes, &p.landmarks, obs, cfg).unwrap();
            (res, t0.elapsed().as_secs_f64())
        };
        let report = |what: &str, res: &BundleResult, secs: f64| {
            let after = middle_rms(&res.keyframes, &p.truth);
            let (t, r) = max_errors(&res.keyframes, &p.truth);
            println!(
                "global BA {what}: {n} keyframes, {} observations, drift at the end {:.3} m \
                 {:.2}°; middle RMS {before:.4} m → {after:.4} m ({:.0}×), worst {t:.4} m \
                 {r:.3}°, {} iterations, {secs:.2} s, {} flagged",
                p.obs.len(),
                end_drift.0,
                end_drift.1,
                before / after,
                res.iterations,
                res.outliers.iter().filter(|o| **o).count()
            );
            after
        };
        let (res, secs) = run(&p.obs, &BundleConfig::global());
        let after = report("(plain, then robust)", &res, secs);
        assert!(after * 20.0 < before, "{before} m → {after} m");
        // The robust round alone gets there too, in more iterations.
        let robust_only = BundleConfig {
            plain_iterations: 0,
            ..BundleConfig::global()
        };
        let (res_robust, secs) = run(&p.obs, &robust_only);
        let after_robust = report("(robust only)", &res_robust, secs);
        assert!(
            after_robust * 20.0 < before,
            "{before} m → {after_robust} m"
        );
        // With 3 % of the observations 20-80 px wrong (of landmarks seen at least 4 times,
        // twice in stereo): still corrected, and every wrong one flagged.
        let mut seen = vec![(0usize, 0usize); p.landmarks.len()];
        for o in &p.obs {
            seen[o.landmark].0 += 1;
            seen[o.landmark].1 += usize::from(o.right_x.is_some());
        }
        let mut rng = ChaCha8Rng::seed_from_u64(50);
        let mut obs = p.obs.clone();
        let mut wrong = vec![false; obs.len()];
        for (o, w) in obs.iter_mut().zip(&mut wrong) {
            let (n, n_stereo) = seen[o.landmark];
            if n >= 4 && n_stereo >= 2 && rng.random_bool(0.04) {
                let angle: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                let shift = Vector2::new(angle.cos(), angle.sin()) * rng.random_range(20.0..80.0);
                o.pixel += shift;
                if let Some(ur) = o.right_x.as_mut() {
                    *ur += shift.x;
                }
                *w = true;
            }
        }
        let n_wrong = wrong.iter().filter(|w| **w).count();
        assert!(n_wrong * 100 >= 3 * obs.len(), "{n_wrong}");
        let (res_wrong, secs) = run(&obs, &BundleConfig::global());
        let after_wrong = report(&format!("with {n_wrong} wrong matches"), &res_wrong, secs);
        assert!(after_wrong * 10.0 < before, "{before} m → {after_wrong} m");
        let missed = wrong
            .iter()
            .zip(&res_wrong.outliers)
            .filter(|(w, o)| **w && !**o)
            .count();
        assert_eq!(missed, 0);
    }

    #[test]
    fn the_result_does_not_depend_on_the_thread_pool() {
        let p = local_problem(0.5, 6);
        let in_pool = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| run(&p, &BundleConfig::local()))
        };
        let (a, b) = (in_pool(1), in_pool(2));
        assert_eq!(a, b);
        assert_eq!(a, run(&p, &BundleConfig::local()));
        // Global BA (plain iterations, more keyframes per task split) as well.
        let d = drift_problem(30, 11);
        let global = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| {
                    bundle_adjust(
                        &rig(),
                        &d.keyframes,
                        &d.landmarks,
                        &d.obs,
                        &BundleConfig::global(),
                    )
                    .unwrap()
                })
        };
        let (a, b, c) = (global(1), global(2), global(3));
        assert_eq!(a, b);
        assert_eq!(a, c);
    }

    #[test]
    fn bad_input_is_an_error_naming_the_offender() {
        let p = local_problem(0.0, 7);
        let cfg = BundleConfig::local();
        let mut obs = p.obs.clone();
        obs[5].landmark = p.landmarks.len() + 3;
        let err = bundle_adjust(&rig(), &p.keyframes, &p.landmarks, &obs, &cfg).unwrap_err();
        assert_eq!(
            err,
            BundleError::UnknownLandmark {
                observation: 5,
                landmark: p.landmarks.len() + 3,
                landmarks: p.landmarks.len()
            }
        );
        assert!(err.to_string().contains("observation 5"), "{err}");
        let mut obs = p.obs.clone();
        obs[2].keyframe = 99;
        assert!(matches!(
            bundle_adjust(&rig(), &p.keyframes, &p.landmarks, &obs, &cfg),
            Err(BundleError::UnknownKeyFrame {
                observation: 2,
                keyframe: 99,
                keyframes: 8
            })
        ));
        let mut obs = p.obs.clone();
        obs[1].camera = 2;
        assert!(matches!(
            bundle_adjust(&rig(), &p.keyframes, &p.landmarks, &obs, &cfg),
            Err(BundleError::UnknownCamera {
                observation: 1,
                camera: 2,
                cameras: 2
            })
        ));
        let mut obs = p.obs.clone();
        obs[4].pixel.x = f64::NAN;
        assert_eq!(
            bundle_adjust(&rig(), &p.keyframes, &p.landmarks, &obs, &cfg),
            Err(BundleError::NonFiniteObservation { observation: 4 })
        );
        let mut obs = p.obs.clone();
        let i = obs.iter().position(|o| o.right_x.is_some()).unwrap();
        obs[i].baseline_m = 0.0;
        assert!(matches!(
            bundle_adjust(&rig(), &p.keyframes, &p.landmarks, &obs, &cfg),
            Err(BundleError::BadBaseline { observation, .. }) if observation == i
        ));
        let mut landmarks = p.landmarks.clone();
        landmarks[7].position.y = f64::INFINITY;
        assert_eq!(
            bundle_adjust(&rig(), &p.keyframes, &landmarks, &p.obs, &cfg),
            Err(BundleError::NonFiniteLandmark { landmark: 7 })
        );
        // Gauge: every keyframe free.
        let free: Vec<BaKeyFrame> = p
            .keyframes
            .iter()
            .map(|k| BaKeyFrame {
                fixed: false,
                ..k.clone()
            })
            .collect();
        assert_eq!(
            bundle_adjust(&rig(), &free, &p.landmarks, &p.obs, &cfg),
            Err(BundleError::NoFixedKeyFrame { keyframes: 8 })
        );
        let bad_cfg = BundleConfig {
            rounds: 0,
            ..cfg.clone()
        };
        assert!(matches!(
            bundle_adjust(&rig(), &p.keyframes, &p.landmarks, &p.obs, &bad_cfg),
            Err(BundleError::Config(_))
        ));
        assert!(BundleConfig::global().validate().is_ok());
    }

    #[test]
    fn weakly_observed_landmarks_stay_finite() {
        // Landmarks seen once (depth free) and a keyframe seeing nothing: damped, finite,
        // and the rest still converges.
        let mut p = local_problem(0.0, 8);
        let mut count = vec![0usize; p.points.len()];
        p.obs.retain(|o| {
            count[o.landmark] += 1;
            o.landmark % 3 != 0 || count[o.landmark] == 1
        });
        p.obs.retain(|o| o.keyframe != 7);
        let res = run(&p, &BundleConfig::local());
        assert!(
            res.landmarks
                .iter()
                .all(|x| x.iter().all(|v| v.is_finite()))
        );
        assert!(
            res.keyframes
                .iter()
                .all(|k| k.translation.vector.iter().all(|v| v.is_finite()))
        );
        let (t, r) = max_errors(&res.keyframes[..7], &p.truth[..7]);
        assert!(t < 1e-3 && r < 0.01, "{t} m, {r}°");
        // A free keyframe that sees nothing does not move.
        let (t7, r7) = pose_error(&res.keyframes[7], &p.keyframes[7].world_from_body);
        assert!(t7 < 1e-12 && r7 < 1e-9, "{t7} m, {r7}°");
    }
    #[test]
    fn the_global_ba_benchmark_runs() {
        let (secs, n) = crate::slam::bench::time_global_ba(12, 40);
        assert!(
            n > 12 * 40 && secs.is_finite() && secs >= 0.0,
            "{n} in {secs} s"
        );
        if let Ok(sizes) = std::env::var("BUNDLE_BENCH") {
            for size in sizes.split(',') {
                let (k, l) = size.split_once('x').unwrap();
                let (secs, n) =
                    crate::slam::bench::time_global_ba(k.parse().unwrap(), l.parse().unwrap());
                println!("global BA {size}: {n} observations, {secs:.3} s");
            }
        }
    }
}
