//! SE(3) pose-graph optimization of the keyframe poses, for loop closure.
//!
//! When the SLAM closes a loop (an AprilTag seen again), the keyframe chain has drifted
//! and the loop edge disagrees with it by the whole drift. Before global bundle adjustment
//! the chain is corrected by a pose graph over the keyframe poses alone (ORB-SLAM's
//! essential-graph step): odometry edges between consecutive keyframes, covisibility edges
//! and the loop edge(s), each a measured relative pose with an information matrix. The
//! stereo rig fixes the scale, so the graph is over SE(3), not Sim(3).
//!
//! **Model.** Node `i` is a keyframe's `world_from_body` pose `T_i = (R_i, t_i)`; an edge
//! `(a, b, Z = a_from_b, Λ)` has the error
//!
//! ```text
//! E = Z⁻¹ · T_a⁻¹ · T_b                 (the identity when the poses agree with Z)
//! e = (t_E, Log(R_E))                   (6-vector: translation x, y, z, then rotation)
//! cost = Σ_edges eᵀ Λ e                 (χ², no ½)
//! ```
//!
//! with `Log` the SO(3) logarithm (a rotation vector, rad). This is the common
//! approximation of the SE(3) logarithm that keeps the translation as it is (the two agree
//! to first order at `E = I` and have the same minimum for a consistent graph); `Λ` is
//! ordered the same way, translation then rotation. A pose is updated on the right,
//! `T ← T · (ρ, Exp(φ))`, i.e. `t ← t + R ρ`, `R ← R Exp(φ)`, with `δ = (ρ, φ)` in the
//! body frame, in the order of `e`. The Jacobians (checked numerically in the tests) are
//!
//! ```text
//! ∂e/∂δ_b = [ R_E   0        ]       ∂e/∂δ_a = [ -R_Zᵀ   [t_E + R_Zᵀ t_Z]× R_Zᵀ ]
//!           [ 0     J_r⁻¹(φ) ]                 [ 0       -J_r⁻¹(φ) R_Eᵀ R_Zᵀ    ]
//! ```
//!
//! with `φ = Log(R_E)` and `J_r⁻¹` SO(3)'s inverse right Jacobian.
//!
//! **Solver.** Levenberg-Marquardt on the normal equations `(H + λ D) δ = -g`, `H = Σ JᵀΛJ`
//! over the free poses in 6×6 blocks, `D` Marquardt's diagonal of `H` plus a small floor
//! (so a free pose that no edge constrains stays well-defined), `λ` divided by 10 after a
//! step that lowers the cost and multiplied by 10 after one that does not. The graph is a
//! long chain plus a few loop and covisibility edges, so `H` is block-sparse; it is solved
//! by the sparse block Cholesky factorization of [`block_cholesky`](super::block_cholesky)
//! (minimum-degree order computed once per [`PoseGraph::optimize`], right-looking
//! numeric factorization over 6×6 blocks). A chain closed by one loop edge is eliminated
//! from its start around the cycle, two off-diagonal blocks per column. With covisibility
//! edges across the chain, on a serpentine over 10 vineyard rows of 100 keyframes, each
//! keyframe also tied to the one beside it in the previous row, `L` has 7 345
//! off-diagonal blocks, where the natural order's envelope (what a profile Cholesky fills)
//! holds 90 899. Each `λ` tried refactors the damped matrix from the undamped `H`.
//!
//! For a chain of N poses with one loop edge this is O(N) per iteration: the 1000-pose
//! loop closure of [`bench_chain`] takes 6 iterations and about 5 ms in all on one core.
//!
//! **Stopping.** After a step that lowers the cost by less than
//! [`PoseGraphConfig::tolerance`] of it or moves no pose by more than 1e-10 (rad, and m
//! relative to `1 + |t|`), when the cost is zero, when no damping gives a lower cost (a
//! minimum to rounding), or after [`PoseGraphConfig::max_iterations`] linearizations;
//! [`PoseGraphResult::converged`] says which (the poses are the best estimate in every
//! case).
//!
//! **Gauge.** The cost is invariant to a rigid motion of the whole graph: at least one
//! pose must be fixed ([`PoseGraphError::NoFixedPose`]). A group of free poses connected to
//! no fixed one is held only by the damping (it moves as little as the damping allows).
//!
//! **Determinism.** Everything runs on one thread in a fixed order (edges in their order,
//! the factorization in the elimination order, ties of the ordering by index), so the
//! result is bit-identical run to run.
//!
//! ```
//! use nalgebra::{Isometry3, Matrix6, Vector3};
//! use vinebench_onboard::slam::pose_graph::{PoseGraph, PoseGraphConfig};
//!
//! // Four poses along x, 1 m apart; odometry says 1 m steps, the loop edge says the last
//! // pose is 3.3 m from the first.
//! let poses = (0..4)
//!     .map(|i| Isometry3::translation(i as f64, 0.0, 0.0))
//!     .collect();
//! let mut graph = PoseGraph::new(poses);
//! graph.fixed[0] = true;
//! for i in 0..3 {
//!     graph.add_current_edge(i, i + 1, Matrix6::identity()).expect("poses exist");
//! }
//! graph.add_edge(0, 3, Isometry3::translation(3.3, 0.0, 0.0), Matrix6::identity());
//! let result = graph.optimize(&PoseGraphConfig::default()).expect("valid graph");
//! assert!(result.converged && result.final_cost < result.initial_cost);
//! // The 0.3 m are shared equally by the four edges.
//! let x3 = graph.poses[3].translation.vector;
//! assert!((x3 - Vector3::new(3.225, 0.0, 0.0)).norm() < 1e-9);
//! ```

use std::time::Instant;

use nalgebra::{
    Isometry3, Matrix3, Matrix6, Quaternion, Translation3, UnitQuaternion, Vector3, Vector6,
};
use thiserror::Error;

use super::block_cholesky::{BlockCholesky, BlockStructure, lower_cholesky_inverse};
use super::{ConfigError, check};

/// Default of [`PoseGraphConfig::max_iterations`].
pub const DEFAULT_MAX_ITERATIONS: usize = 20;

/// Default of [`PoseGraphConfig::tolerance`]: near the minimum a step lowers the cost by
/// about the excess left, so the result is within ~1e-8 of the minimum cost.
pub const DEFAULT_TOLERANCE: f64 = 1e-8;

/// Levenberg-Marquardt damping of the first step (relative to `H`'s diagonal): about a
/// Gauss-Newton step, which a pose graph usually takes.
const INITIAL_LAMBDA: f64 = 1e-6;

/// Lower bound of `λ` after kept steps.
const MIN_LAMBDA: f64 = 1e-12;

/// Above this `λ` no step lowers the cost: the poses are at a minimum to rounding.
const MAX_LAMBDA: f64 = 1e12;

/// A kept step below this (rad, and m relative to `1 + |t|` of its pose) on every pose
/// ends the optimization: the poses no longer move (e.g. a consistent graph whose cost is
/// only rounding, which falls by orders of magnitude every step).
const STEP_TOLERANCE: f64 = 1e-10;

/// Floor of the damping scale, relative to the largest diagonal entry of `H`.
const DAMPING_FLOOR: f64 = 1e-9;

/// An information matrix must be symmetric to this fraction of its largest entry.
const SYMMETRY_TOLERANCE: f64 = 1e-9;

/// An information matrix plus this fraction of its trace (times `I`) must be positive
/// definite (positive semi-definite up to rounding).
const PSD_TOLERANCE: f64 = 1e-9;

/// Below this angle (rad) the series of `J_r⁻¹`'s coefficient is used.
const SMALL_ANGLE: f64 = 1e-4;

/// One relative-pose measurement between two poses of the graph.
#[derive(Clone, Debug, PartialEq)]
pub struct PoseGraphEdge {
    /// Index of the first pose.
    pub a: usize,
    /// Index of the second pose.
    pub b: usize,
    /// The measured pose of `b`'s body in `a`'s body frame (maps points in `b` to `a`).
    pub a_from_b: Isometry3<f64>,
    /// Information (inverse covariance) of the error, ordered translation (x, y, z, m)
    /// then rotation (rx, ry, rz, rad) in the tangent space of the error (see the module
    /// docs). Symmetric, positive semi-definite.
    pub information: Matrix6<f64>,
}

/// A pose graph: keyframe poses, which of them are held, and the relative-pose edges.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct PoseGraph {
    /// `world_from_body` of every node (maps body points to world): the initial guess,
    /// the optimized poses after [`PoseGraph::optimize`].
    pub poses: Vec<Isometry3<f64>>,
    /// Held at its pose during the optimization, one per pose; at least one (the gauge).
    pub fixed: Vec<bool>,
    /// The measurements.
    pub edges: Vec<PoseGraphEdge>,
}

/// Settings of [`PoseGraph::optimize`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseGraphConfig {
    /// Most linearizations (Levenberg-Marquardt iterations).
    pub max_iterations: usize,
    /// Stop after a step that lowers the cost by less than this fraction of it.
    pub tolerance: f64,
}

impl Default for PoseGraphConfig {
    /// 20 iterations, relative cost decrease 1e-8.
    fn default() -> PoseGraphConfig {
        PoseGraphConfig {
            max_iterations: DEFAULT_MAX_ITERATIONS,
            tolerance: DEFAULT_TOLERANCE,
        }
    }
}

impl PoseGraphConfig {
    /// Checks the ranges.
    pub fn validate(&self) -> Result<(), ConfigError> {
        check(
            (1..=10_000).contains(&self.max_iterations),
            "pose graph iterations must be in [1, 10000]",
        )?;
        check(
            self.tolerance.is_finite() && (0.0..1.0).contains(&self.tolerance),
            "the pose graph tolerance must be in [0, 1)",
        )
    }
}

/// What [`PoseGraph::optimize`] did.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PoseGraphResult {
    /// [`PoseGraph::cost`] before.
    pub initial_cost: f64,
    /// [`PoseGraph::cost`] after.
    pub final_cost: f64,
    /// Linearizations (Levenberg-Marquardt iterations) done.
    pub iterations: usize,
    /// A stopping criterion was met (relative decrease below the tolerance, zero cost, or
    /// no step lowers the cost); `false` when `max_iterations` ran out first, the poses
    /// then being the best estimate found.
    pub converged: bool,
}

/// Why a pose graph cannot be optimized.
#[derive(Clone, Debug, Error, PartialEq)]
pub enum PoseGraphError {
    /// The settings are out of range.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// `fixed` does not have one flag per pose.
    #[error("the pose graph has {poses} poses but {fixed} fixed flags")]
    FixedLength {
        /// Poses in the graph.
        poses: usize,
        /// Flags in `fixed`.
        fixed: usize,
    },
    /// Every pose is free: the graph's placement is undetermined (gauge freedom).
    #[error("the pose graph needs at least one fixed pose (gauge), none of {poses} is")]
    NoFixedPose {
        /// Poses in the graph.
        poses: usize,
    },
    /// An edge names a pose the graph does not have.
    #[error("edge {edge} names pose {pose}, the graph has {poses}")]
    EdgeOutOfRange {
        /// The edge (for [`PoseGraph::add_current_edge`], the index it would have had).
        edge: usize,
        /// The pose it names.
        pose: usize,
        /// Poses in the graph.
        poses: usize,
    },
    /// An edge joins a pose to itself.
    #[error("edge {edge} joins pose {pose} to itself")]
    SelfEdge {
        /// The edge.
        edge: usize,
        /// The pose.
        pose: usize,
    },
    /// A pose has a non-finite component.
    #[error("pose {pose} is not finite")]
    NonFinitePose {
        /// The pose.
        pose: usize,
    },
    /// An edge's measurement or information matrix has a non-finite entry.
    #[error("edge {edge} has a non-finite measurement or information matrix")]
    NonFiniteEdge {
        /// The edge.
        edge: usize,
    },
    /// An edge's information matrix is not symmetric positive semi-definite.
    #[error("the information matrix of edge {edge} is not symmetric positive semi-definite")]
    InvalidInformation {
        /// The edge.
        edge: usize,
    },
    /// The damped normal equations could not be factored even with the largest damping.
    #[error("the pose graph's normal equations are singular at iteration {iteration}")]
    SingularSystem {
        /// The iteration (1-based).
        iteration: usize,
    },
}

impl PoseGraph {
    /// A graph over `poses` (`world_from_body`), none fixed and no edges.
    pub fn new(poses: Vec<Isometry3<f64>>) -> PoseGraph {
        let fixed = vec![false; poses.len()];
        PoseGraph {
            poses,
            fixed,
            edges: Vec::new(),
        }
    }

    /// Adds the measurement `a_from_b` between poses `a` and `b` with its `information`
    /// (see [`PoseGraphEdge`]). The indices are checked by [`PoseGraph::validate`] (and
    /// so by [`PoseGraph::optimize`]).
    pub fn add_edge(
        &mut self,
        a: usize,
        b: usize,
        a_from_b: Isometry3<f64>,
        information: Matrix6<f64>,
    ) {
        self.edges.push(PoseGraphEdge {
            a,
            b,
            a_from_b,
            information,
        });
    }

    /// [`PoseGraph::add_edge`] with `a_from_b` taken from the current poses: an odometry
    /// or covisibility edge that keeps the current relative pose.
    pub fn add_current_edge(
        &mut self,
        a: usize,
        b: usize,
        information: Matrix6<f64>,
    ) -> Result<(), PoseGraphError> {
        let poses = self.poses.len();
        for pose in [a, b] {
            if pose >= poses {
                return Err(PoseGraphError::EdgeOutOfRange {
                    edge: self.edges.len(),
                    pose,
                    poses,
                });
            }
        }
        let a_from_b = self.poses[a].inv_mul(&self.poses[b]);
        self.add_edge(a, b, a_from_b, information);
        Ok(())
    }

    /// The cost `Σ eᵀ Λ e` over every edge at the current poses (see the module docs);
    /// NaN when an edge names a pose the graph does not have.
    pub fn cost(&self) -> f64 {
        cost_of(&self.poses, &self.edges)
    }

    /// Checks the graph: one `fixed` flag per pose and at least one set, finite poses,
    /// edges between two distinct existing poses with finite measurements and symmetric
    /// positive semi-definite information matrices.
    pub fn validate(&self) -> Result<(), PoseGraphError> {
        let poses = self.poses.len();
        if self.fixed.len() != poses {
            return Err(PoseGraphError::FixedLength {
                poses,
                fixed: self.fixed.len(),
            });
        }
        if !self.fixed.iter().any(|&f| f) {
            return Err(PoseGraphError::NoFixedPose { poses });
        }
        if let Some(pose) = self.poses.iter().position(|p| !is_finite(p)) {
            return Err(PoseGraphError::NonFinitePose { pose });
        }
        for (edge, e) in self.edges.iter().enumerate() {
            for pose in [e.a, e.b] {
                if pose >= poses {
                    return Err(PoseGraphError::EdgeOutOfRange { edge, pose, poses });
                }
            }
            if e.a == e.b {
                return Err(PoseGraphError::SelfEdge { edge, pose: e.a });
            }
            if !is_finite(&e.a_from_b) || e.information.iter().any(|x| !x.is_finite()) {
                return Err(PoseGraphError::NonFiniteEdge { edge });
            }
            if !is_valid_information(&e.information) {
                return Err(PoseGraphError::InvalidInformation { edge });
            }
        }
        Ok(())
    }

    /// Moves the free poses to minimize [`PoseGraph::cost`] (Levenberg-Marquardt with a
    /// sparse block Cholesky solve, see the module docs). The fixed poses are not touched.
    pub fn optimize(&mut self, cfg: &PoseGraphConfig) -> Result<PoseGraphResult, PoseGraphError> {
        cfg.validate()?;
        self.validate()?;
        let initial_cost = self.cost();
        let mut result = PoseGraphResult {
            initial_cost,
            final_cost: initial_cost,
            iterations: 0,
            converged: false,
        };
        let structure = Structure::new(&self.fixed, &self.edges);
        if structure.len() == 0 || initial_cost == 0.0 {
            result.converged = true;
            return Ok(result);
        }
        let mut normal = Normal::new(&structure);
        let mut work = Factor::new(&structure);
        let mut candidate = self.poses.clone();
        let mut cost = initial_cost;
        let mut lambda = INITIAL_LAMBDA;
        while result.iterations < cfg.max_iterations {
            result.iterations += 1;
            structure.linearize(&self.poses, &self.edges, &mut normal);
            if normal.grad.iter().all(|g| g.iter().all(|&x| x == 0.0)) {
                result.converged = true;
                break;
            }
            let max_diag = normal
                .diag
                .iter()
                .fold(0.0_f64, |m, d| (0..6).fold(m, |m, i| m.max(d[(i, i)])));
            let floor = (DAMPING_FLOOR * max_diag).max(f64::MIN_POSITIVE);
            let mut factored = false;
            let mut accepted = None;
            while lambda <= MAX_LAMBDA {
                if !work.solve(&structure, &normal, lambda, floor) {
                    lambda *= 10.0;
                    continue;
                }
                factored = true;
                for (p, &pose) in structure.pose_at.iter().enumerate() {
                    candidate[pose] = retract(&self.poses[pose], &work.x[p]);
                }
                let new_cost = cost_of(&candidate, &self.edges);
                if new_cost.is_finite() && new_cost < cost {
                    accepted = Some(new_cost);
                    break;
                }
                lambda *= 10.0;
            }
            let Some(new_cost) = accepted else {
                if !factored {
                    return Err(PoseGraphError::SingularSystem {
                        iteration: result.iterations,
                    });
                }
                // No damping lowers the cost: a minimum to rounding.
                result.converged = true;
                break;
            };
            let mut negligible = true;
            for (&pose, step) in structure.pose_at.iter().zip(&work.x) {
                let scale = 1.0 + self.poses[pose].translation.vector.amax();
                negligible &= step.fixed_rows::<3>(0).amax() <= STEP_TOLERANCE * scale
                    && step.fixed_rows::<3>(3).amax() <= STEP_TOLERANCE;
                self.poses[pose] = candidate[pose];
            }
            let decrease = (cost - new_cost) / cost;
            cost = new_cost;
            lambda = (lambda / 10.0).max(MIN_LAMBDA);
            if cost == 0.0 || decrease < cfg.tolerance || negligible {
                result.converged = true;
                break;
            }
        }
        result.final_cost = cost;
        Ok(result)
    }
}

/// Seconds taken by [`PoseGraph::optimize`] (default settings) on a loop closure over a
/// chain of `n` poses: a circle of 0.5 m steps whose odometry drifted (0.01°/step of yaw,
/// 0.005°/step of pitch, 1 % of scale), odometry edges at the drifted relative poses and
/// one loop edge from pose `n - 1` to pose 0 at the true relative pose, all with dense
/// 6×6 information matrices, pose 0 fixed. Single-threaded.
pub fn bench_chain(n: usize) -> Result<f64, PoseGraphError> {
    let mut graph = drifted_circle(n)?;
    let start = Instant::now();
    graph.optimize(&PoseGraphConfig::default())?;
    Ok(start.elapsed().as_secs_f64())
}

/// The graph of [`bench_chain`] (pose 0 fixed; needs `n >= 2` for the loop edge).
fn drifted_circle(n: usize) -> Result<PoseGraph, PoseGraphError> {
    const STEP_M: f64 = 0.5;
    let yaw_step = std::f64::consts::TAU / n.max(1) as f64;
    let radius = STEP_M / yaw_step;
    let truth: Vec<Isometry3<f64>> = (0..n)
        .map(|k| {
            let yaw = yaw_step * k as f64;
            let z = 0.3 * (3.0 * yaw).sin();
            Isometry3::from_parts(
                Translation3::new(radius * yaw.sin(), radius * (1.0 - yaw.cos()), z),
                UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
            )
        })
        .collect();
    let bias = Isometry3::from_parts(
        Translation3::new(0.01 * STEP_M, 0.0, 0.0),
        UnitQuaternion::from_euler_angles(0.0, 0.005_f64.to_radians(), 0.01_f64.to_radians()),
    );
    let mut drifted = Vec::with_capacity(n);
    for k in 0..n {
        let pose = match k {
            0 => truth[0],
            _ => drifted[k - 1] * truth[k - 1].inv_mul(&truth[k]) * bias,
        };
        drifted.push(pose);
    }
    let information = dense_information(0.02, 0.002);
    let mut graph = PoseGraph::new(drifted);
    if let Some(first) = graph.fixed.first_mut() {
        *first = true;
    }
    for k in 1..n {
        graph.add_current_edge(k - 1, k, information)?;
    }
    if n >= 2 {
        graph.add_edge(n - 1, 0, truth[n - 1].inv_mul(&truth[0]), information);
    }
    Ok(graph)
}

/// A dense information matrix `S Sᵀ` with `S` lower triangular, diagonal
/// `(1/σ_t, 1/σ_t, 1/σ_t, 1/σ_r, …)` and 10 % couplings below it.
fn dense_information(sigma_t: f64, sigma_r: f64) -> Matrix6<f64> {
    let mut s = Matrix6::zeros();
    for i in 0..6 {
        let d = if i < 3 { 1.0 / sigma_t } else { 1.0 / sigma_r };
        s[(i, i)] = d;
        for j in 0..i {
            s[(i, j)] = 0.1 * d * if (i + j) % 2 == 0 { 1.0 } else { -1.0 };
        }
    }
    s * s.transpose()
}

/// All components finite (translation and quaternion).
fn is_finite(pose: &Isometry3<f64>) -> bool {
    pose.translation.vector.iter().all(|x| x.is_finite())
        && pose.rotation.coords.iter().all(|x| x.is_finite())
}

/// Symmetric (relative to its largest entry) and positive semi-definite up to rounding.
fn is_valid_information(m: &Matrix6<f64>) -> bool {
    let scale = m.amax();
    if (m - m.transpose()).amax() > SYMMETRY_TOLERANCE * scale {
        return false;
    }
    let shift = (PSD_TOLERANCE * m.trace()).max(f64::MIN_POSITIVE);
    lower_cholesky_inverse(&(m + Matrix6::identity() * shift)).is_some()
}

/// `Σ eᵀ Λ e` in edge order; NaN when an edge names a missing pose.
fn cost_of(poses: &[Isometry3<f64>], edges: &[PoseGraphEdge]) -> f64 {
    let mut cost = 0.0;
    for edge in edges {
        let (Some(a), Some(b)) = (poses.get(edge.a), poses.get(edge.b)) else {
            return f64::NAN;
        };
        let e = edge_error(a, b, &edge.a_from_b).1;
        cost += e.dot(&(edge.information * e));
    }
    cost
}

/// `[v]×`: `skew(v) · w = v × w`.
fn skew(v: &Vector3<f64>) -> Matrix3<f64> {
    v.cross_matrix()
}

/// SO(3) logarithm: the rotation vector (rad, angle in [0, π]).
fn so3_log(q: &UnitQuaternion<f64>) -> Vector3<f64> {
    let (w, v) = if q.w < 0.0 {
        (-q.w, -q.imag())
    } else {
        (q.w, q.imag())
    };
    let n = v.norm();
    if n < 1e-8 {
        // θ = 2 atan(n / w) ≈ 2 n / w (1 - n² / (3 w²)).
        v * (2.0 / w * (1.0 - n * n / (3.0 * w * w)))
    } else {
        v * (2.0 * n.atan2(w) / n)
    }
}

/// SO(3) exponential of a rotation vector (rad).
fn so3_exp(phi: &Vector3<f64>) -> UnitQuaternion<f64> {
    let theta = phi.norm();
    let half = 0.5 * theta;
    let (w, k) = if theta < 1e-8 {
        (1.0 - half * half / 2.0, 0.5)
    } else {
        (half.cos(), half.sin() / theta)
    };
    UnitQuaternion::new_normalize(Quaternion::new(w, k * phi.x, k * phi.y, k * phi.z))
}

/// SO(3)'s inverse right Jacobian: `Log(Exp(φ) Exp(δ)) ≈ φ + J_r⁻¹(φ) δ`.
fn so3_right_jacobian_inverse(phi: &Vector3<f64>) -> Matrix3<f64> {
    let theta2 = phi.norm_squared();
    let theta = theta2.sqrt();
    let k = skew(phi);
    // 1/θ² - (1 + cos θ) / (2 θ sin θ), written with θ/2 so that it stays finite at π.
    let c = if theta < SMALL_ANGLE {
        1.0 / 12.0 + theta2 / 720.0
    } else {
        let half = 0.5 * theta;
        1.0 / theta2 - half.cos() / (2.0 * theta * half.sin())
    };
    Matrix3::identity() + k * 0.5 + k * k * c
}

/// The right update `pose · (ρ, Exp(φ))`, `δ = (ρ, φ)`: `t + R ρ`, `R Exp(φ)`.
fn retract(pose: &Isometry3<f64>, delta: &Vector6<f64>) -> Isometry3<f64> {
    let step = Isometry3::from_parts(
        Translation3::new(delta[0], delta[1], delta[2]),
        so3_exp(&Vector3::new(delta[3], delta[4], delta[5])),
    );
    let mut out = pose * step;
    out.rotation.renormalize();
    out
}

/// The error of an edge measuring `a_from_b` when the poses give `actual`:
/// `e = (t_E, Log(R_E))` of `E = a_from_b⁻¹ · actual` (translation, then rotation), the
/// tangent in which [`PoseGraphEdge::information`] is expressed.
pub fn relative_error(a_from_b: &Isometry3<f64>, actual: &Isometry3<f64>) -> Vector6<f64> {
    error_vector(&a_from_b.inv_mul(actual))
}

/// `(t_E, Log(R_E))` of `E`.
fn error_vector(err: &Isometry3<f64>) -> Vector6<f64> {
    let t = err.translation.vector;
    let r = so3_log(&err.rotation);
    Vector6::new(t.x, t.y, t.z, r.x, r.y, r.z)
}

/// `E = Z⁻¹ T_a⁻¹ T_b` and `e = (t_E, Log(R_E))`.
fn edge_error(
    world_from_a: &Isometry3<f64>,
    world_from_b: &Isometry3<f64>,
    a_from_b: &Isometry3<f64>,
) -> (Isometry3<f64>, Vector6<f64>) {
    let err = a_from_b.inv_mul(&world_from_a.inv_mul(world_from_b));
    (err, error_vector(&err))
}

/// The error and its Jacobians `∂e/∂δ_a`, `∂e/∂δ_b` (module docs).
fn linearize_edge(
    world_from_a: &Isometry3<f64>,
    world_from_b: &Isometry3<f64>,
    a_from_b: &Isometry3<f64>,
) -> (Vector6<f64>, Matrix6<f64>, Matrix6<f64>) {
    let (err, e) = edge_error(world_from_a, world_from_b, a_from_b);
    let phi = Vector3::new(e[3], e[4], e[5]);
    let jr_inv = so3_right_jacobian_inverse(&phi);
    let rz_t = a_from_b
        .rotation
        .to_rotation_matrix()
        .into_inner()
        .transpose();
    let re = err.rotation.to_rotation_matrix().into_inner();
    let tz_in_b = rz_t * a_from_b.translation.vector;
    let mut ja = Matrix6::zeros();
    ja.fixed_view_mut::<3, 3>(0, 0).copy_from(&(-rz_t));
    ja.fixed_view_mut::<3, 3>(0, 3)
        .copy_from(&(skew(&(err.translation.vector + tz_in_b)) * rz_t));
    ja.fixed_view_mut::<3, 3>(3, 3)
        .copy_from(&(-(jr_inv * re.transpose() * rz_t)));
    let mut jb = Matrix6::zeros();
    jb.fixed_view_mut::<3, 3>(0, 0).copy_from(&re);
    jb.fixed_view_mut::<3, 3>(3, 3).copy_from(&jr_inv);
    (e, ja, jb)
}

/// The normal equations' block structure over the free poses ([`BlockStructure`]: the
/// elimination order and the structure of `L`) and where each edge's block goes.
struct Structure {
    /// The free poses and their couplings, in elimination order.
    blocks: BlockStructure,
    /// Position in the elimination order of each pose (`None`: fixed).
    position: Vec<Option<usize>>,
    /// The pose at each position.
    pose_at: Vec<usize>,
    /// Per edge between two free poses: its off-diagonal slot and whether `a` is the row.
    edge_slot: Vec<Option<(usize, bool)>>,
}

impl Structure {
    /// The minimum-degree ordering of the free poses over the edges and the structure of
    /// its Cholesky factor.
    fn new(fixed: &[bool], edges: &[PoseGraphEdge]) -> Structure {
        let mut var_of = vec![None; fixed.len()];
        let mut pose_of_var = Vec::new();
        for (pose, &f) in fixed.iter().enumerate() {
            if !f {
                var_of[pose] = Some(pose_of_var.len());
                pose_of_var.push(pose);
            }
        }
        let blocks = BlockStructure::new(
            pose_of_var.len(),
            edges
                .iter()
                .filter_map(|e| Some((var_of[e.a]?, var_of[e.b]?))),
        );
        let edge_slot = edges
            .iter()
            .map(|e| match (var_of[e.a], var_of[e.b]) {
                (Some(a), Some(b)) if a != b => Some(blocks.block(a, b)),
                _ => None,
            })
            .collect();
        Structure {
            position: var_of
                .iter()
                .map(|v| v.map(|v| blocks.position(v)))
                .collect(),
            pose_at: (0..blocks.len())
                .map(|p| pose_of_var[blocks.variable_at(p)])
                .collect(),
            blocks,
            edge_slot,
        }
    }

    /// Free poses.
    fn len(&self) -> usize {
        self.pose_at.len()
    }

    /// `H = Σ JᵀΛJ` and `g = Σ JᵀΛe` over the free poses, in edge order.
    fn linearize(&self, poses: &[Isometry3<f64>], edges: &[PoseGraphEdge], out: &mut Normal) {
        out.diag.fill(Matrix6::zeros());
        out.off.fill(Matrix6::zeros());
        out.grad.fill(Vector6::zeros());
        for (edge, slot) in edges.iter().zip(&self.edge_slot) {
            let (pa, pb) = (self.position[edge.a], self.position[edge.b]);
            if pa.is_none() && pb.is_none() {
                continue;
            }
            let (e, ja, jb) = linearize_edge(&poses[edge.a], &poses[edge.b], &edge.a_from_b);
            let ja_t_w = ja.tr_mul(&edge.information);
            let jb_t_w = jb.tr_mul(&edge.information);
            if let Some(p) = pa {
                out.diag[p] += ja_t_w * ja;
                out.grad[p] += ja_t_w * e;
            }
            if let Some(p) = pb {
                out.diag[p] += jb_t_w * jb;
                out.grad[p] += jb_t_w * e;
            }
            if let Some((s, a_is_row)) = *slot {
                out.off[s] += if a_is_row { ja_t_w * jb } else { jb_t_w * ja };
            }
        }
    }
}

/// The normal equations in the blocks of [`Structure`].
struct Normal {
    /// Diagonal blocks, by position.
    diag: Vec<Matrix6<f64>>,
    /// Off-diagonal (lower) blocks, by slot; zero at fill slots.
    off: Vec<Matrix6<f64>>,
    /// The gradient `JᵀΛe`, by position.
    grad: Vec<Vector6<f64>>,
}

impl Normal {
    /// Zeros for `structure`.
    fn new(structure: &Structure) -> Normal {
        Normal {
            diag: vec![Matrix6::zeros(); structure.len()],
            off: vec![Matrix6::zeros(); structure.blocks.n_blocks()],
            grad: vec![Vector6::zeros(); structure.len()],
        }
    }
}

/// The factorization's buffers and the step.
struct Factor {
    /// The damped diagonal blocks.
    damped: Vec<Matrix6<f64>>,
    /// The factorization.
    cholesky: BlockCholesky,
    /// The step `δ` of each position.
    x: Vec<Vector6<f64>>,
}

impl Factor {
    /// Buffers for `structure`.
    fn new(structure: &Structure) -> Factor {
        Factor {
            damped: vec![Matrix6::zeros(); structure.len()],
            cholesky: BlockCholesky::new(&structure.blocks),
            x: vec![Vector6::zeros(); structure.len()],
        }
    }

    /// Solves `(H + λ (diag(H) + floor)) x = -g` into `self.x`; `false` when a pivot
    /// block is not positive definite.
    fn solve(&mut self, structure: &Structure, normal: &Normal, lambda: f64, floor: f64) -> bool {
        for (d, h) in self.damped.iter_mut().zip(&normal.diag) {
            *d = *h;
            for i in 0..6 {
                d[(i, i)] += lambda * (h[(i, i)] + floor);
            }
        }
        if !self
            .cholesky
            .factor(&structure.blocks, &self.damped, &normal.off)
        {
            return false;
        }
        for (x, g) in self.x.iter_mut().zip(&normal.grad) {
            *x = -g;
        }
        self.cholesky.solve(&structure.blocks, &mut self.x);
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{DMatrix, DVector};
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn random_vector3(rng: &mut ChaCha8Rng, scale: f64) -> Vector3<f64> {
        Vector3::new(
            rng.random_range(-scale..scale),
            rng.random_range(-scale..scale),
            rng.random_range(-scale..scale),
        )
    }

    /// A random pose: translation in ±`t` m, rotation vector in ±`r` rad per axis.
    fn random_pose(rng: &mut ChaCha8Rng, t: f64, r: f64) -> Isometry3<f64> {
        Isometry3::from_parts(
            Translation3::from(random_vector3(rng, t)),
            UnitQuaternion::from_scaled_axis(random_vector3(rng, r)),
        )
    }

    fn pose_distance(a: &Isometry3<f64>, b: &Isometry3<f64>) -> (f64, f64) {
        let d = a.inv_mul(b);
        (d.translation.vector.norm(), d.rotation.angle())
    }

    fn information(sigma_t: f64, sigma_r: f64) -> Matrix6<f64> {
        let mut m = Matrix6::zeros();
        for i in 0..6 {
            m[(i, i)] = if i < 3 {
                sigma_t.powi(-2)
            } else {
                sigma_r.powi(-2)
            };
        }
        m
    }

    #[test]
    fn so3_log_inverts_exp() {
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        for scale in [1e-10, 1e-5, 0.3, 1.7] {
            for _ in 0..50 {
                let phi = random_vector3(&mut rng, scale);
                let back = so3_log(&so3_exp(&phi));
                assert!(
                    (back - phi).norm() <= 1e-12 * (1.0 + phi.norm()),
                    "{phi} -> {back}"
                );
                let nalgebra = UnitQuaternion::from_scaled_axis(phi);
                assert!(so3_exp(&phi).angle_to(&nalgebra) < 1e-12);
            }
        }
    }

    /// Analytic Jacobians against central differences of the error through the same
    /// right update, including errors with large rotations (2.5 rad).
    #[test]
    fn jacobians_match_numeric_differentiation() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let h = 1e-6;
        for case in 0..40 {
            let pa = random_pose(&mut rng, 5.0, 3.0);
            let pb = random_pose(&mut rng, 5.0, 3.0);
            let err_angle = [1e-9, 0.01, 0.5, 1.5, 2.5][case % 5];
            let axis = random_vector3(&mut rng, 1.0).normalize();
            let noise = Isometry3::from_parts(
                Translation3::from(random_vector3(&mut rng, 1.0)),
                UnitQuaternion::from_scaled_axis(axis * err_angle),
            );
            let z = pa.inv_mul(&pb) * noise;
            let (e0, ja, jb) = linearize_edge(&pa, &pb, &z);
            assert!((e0 - edge_error(&pa, &pb, &z).1).norm() < 1e-15);
            for k in 0..6 {
                let mut d = Vector6::zeros();
                d[k] = h;
                let num_a = (edge_error(&retract(&pa, &d), &pb, &z).1
                    - edge_error(&retract(&pa, &(-d)), &pb, &z).1)
                    / (2.0 * h);
                let num_b = (edge_error(&pa, &retract(&pb, &d), &z).1
                    - edge_error(&pa, &retract(&pb, &(-d)), &z).1)
                    / (2.0 * h);
                let (ea, eb) = ((num_a - ja.column(k)).norm(), (num_b - jb.column(k)).norm());
                assert!(
                    ea < 1e-7 * (1.0 + num_a.norm()),
                    "case {case} (angle {err_angle}) ∂e/∂δa[{k}]: analytic {} numeric {} (diff {ea:e})",
                    ja.column(k).transpose(),
                    num_a.transpose()
                );
                assert!(
                    eb < 1e-7 * (1.0 + num_b.norm()),
                    "case {case} (angle {err_angle}) ∂e/∂δb[{k}]: analytic {} numeric {} (diff {eb:e})",
                    jb.column(k).transpose(),
                    num_b.transpose()
                );
            }
        }
    }

    /// The sparse block solve against a dense solve of the same damped normal equations,
    /// on a random graph (chain, random long edges, two fixed poses).
    #[test]
    fn sparse_solve_matches_dense() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let n = 30;
        let poses: Vec<_> = (0..n).map(|_| random_pose(&mut rng, 3.0, 1.0)).collect();
        let mut graph = PoseGraph::new(poses);
        graph.fixed[4] = true;
        graph.fixed[17] = true;
        let info = dense_information(0.1, 0.05);
        for k in 1..n {
            let z = random_pose(&mut rng, 3.0, 1.0);
            graph.add_edge(k - 1, k, z, info);
        }
        for _ in 0..25 {
            let a = rng.random_range(0..n);
            let b = rng.random_range(0..n);
            if a != b {
                let z = random_pose(&mut rng, 3.0, 1.0);
                graph.add_edge(a, b, z, info);
            }
        }
        let structure = Structure::new(&graph.fixed, &graph.edges);
        let m = structure.len();
        assert_eq!(m, n - 2);
        let mut normal = Normal::new(&structure);
        structure.linearize(&graph.poses, &graph.edges, &mut normal);
        let mut factor = Factor::new(&structure);
        let (lambda, floor) = (0.01, 0.5);
        assert!(factor.solve(&structure, &normal, lambda, floor));

        // Dense normal equations indexed by pose order (not the elimination order).
        let var: Vec<Option<usize>> = {
            let mut next = 0;
            graph
                .fixed
                .iter()
                .map(|&f| {
                    (!f).then(|| {
                        next += 1;
                        next - 1
                    })
                })
                .collect()
        };
        let mut h = DMatrix::<f64>::zeros(6 * m, 6 * m);
        let mut g = DVector::<f64>::zeros(6 * m);
        for edge in &graph.edges {
            let (e, ja, jb) =
                linearize_edge(&graph.poses[edge.a], &graph.poses[edge.b], &edge.a_from_b);
            let blocks = [(var[edge.a], ja), (var[edge.b], jb)];
            for &(vi, ji) in &blocks {
                let Some(vi) = vi else { continue };
                let gi = ji.transpose() * edge.information * e;
                for r in 0..6 {
                    g[6 * vi + r] += gi[r];
                }
                for &(vj, jj) in &blocks {
                    let Some(vj) = vj else { continue };
                    let hij = ji.transpose() * edge.information * jj;
                    for r in 0..6 {
                        for c in 0..6 {
                            h[(6 * vi + r, 6 * vj + c)] += hij[(r, c)];
                        }
                    }
                }
            }
        }
        for i in 0..6 * m {
            h[(i, i)] += lambda * (h[(i, i)] + floor);
        }
        let x = h.cholesky().expect("damped H is SPD").solve(&(-g));
        let mut max_diff: f64 = 0.0;
        for (pose, v) in var.iter().enumerate() {
            let Some(v) = v else { continue };
            let p = structure.position[pose].expect("free");
            for r in 0..6 {
                max_diff = max_diff.max((factor.x[p][r] - x[6 * v + r]).abs());
            }
        }
        assert!(
            max_diff < 1e-9 * (1.0 + x.amax()),
            "sparse vs dense step differ by {max_diff:e} (|x| {})",
            x.amax()
        );
    }

    /// Edges equal to the current relative poses: zero cost (to rounding) and the
    /// optimizer leaves the poses where they are.
    #[test]
    fn consistent_graph_is_unchanged() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let mut poses = vec![Isometry3::identity()];
        for _ in 1..60 {
            let step = random_pose(&mut rng, 1.0, 0.3);
            poses.push(poses[poses.len() - 1] * step);
        }
        let mut graph = PoseGraph::new(poses.clone());
        graph.fixed[0] = true;
        let info = dense_information(0.02, 0.002);
        for k in 1..60 {
            graph.add_current_edge(k - 1, k, info).expect("in range");
        }
        for k in (0..55).step_by(5) {
            graph.add_current_edge(k + 5, k, info).expect("in range");
        }
        graph.add_current_edge(59, 0, info).expect("in range");
        let cost = graph.cost();
        assert!(cost < 1e-16, "cost of a consistent graph {cost:e}");
        let result = graph.optimize(&PoseGraphConfig::default()).expect("valid");
        assert!(result.converged, "{result:?}");
        assert!(result.final_cost <= result.initial_cost);
        for (k, (before, after)) in poses.iter().zip(&graph.poses).enumerate() {
            let (dt, dr) = pose_distance(before, after);
            assert!(
                dt < 1e-12 && dr < 1e-12,
                "pose {k} moved {dt:e} m {dr:e} rad"
            );
        }
    }

    /// The position-only least squares `Σ (x_b - x_a - z)ᵀ Λ_t (x_b - x_a - z)` with
    /// `x_fixed = 0`, solved densely: the independent expectation of the closed-form test.
    fn position_only_optimum(
        n: usize,
        edges: &[(usize, usize, Vector3<f64>, Matrix3<f64>)],
    ) -> Vec<Vector3<f64>> {
        // Unknowns x_1..x_{n-1} (x_0 = 0 is fixed).
        let m = 3 * (n - 1);
        let mut h = DMatrix::<f64>::zeros(m, m);
        let mut rhs = DVector::<f64>::zeros(m);
        for &(a, b, z, w) in edges {
            // r = x_b - x_a - z; d r / d x_b = I, d r / d x_a = -I.
            let terms = [(a, -1.0), (b, 1.0)];
            for &(i, si) in &terms {
                if i == 0 {
                    continue;
                }
                let bi = 3 * (i - 1);
                let wz = w * z;
                for r in 0..3 {
                    rhs[bi + r] += si * wz[r];
                }
                for &(j, sj) in &terms {
                    if j == 0 {
                        continue;
                    }
                    let bj = 3 * (j - 1);
                    for r in 0..3 {
                        for c in 0..3 {
                            h[(bi + r, bj + c)] += si * sj * w[(r, c)];
                        }
                    }
                }
            }
        }
        let x = h.lu().solve(&rhs).expect("anchored chain");
        let mut out = vec![Vector3::zeros()];
        for k in 1..n {
            out.push(Vector3::new(
                x[3 * (k - 1)],
                x[3 * (k - 1) + 1],
                x[3 * (k - 1) + 2],
            ));
        }
        out
    }

    /// A straight chain along x with identical odometry edges and a loop edge that says
    /// the last pose is offset by `d` along the line from what the chain says. With
    /// rotation-free poses, translations along one line and information matrices for
    /// which that line is an eigenvector of the translation block (no translation-rotation
    /// coupling), every residual is along the line, the rotation gradient `-(e_t + z) ×
    /// Λ_t e_t` vanishes and the Gauss-Newton system separates: the rotations stay the
    /// identity and the positions solve the linear least squares on positions exactly.
    /// Equal (identity) weights give the linear distribution `x_k = k (s + d / N)`
    /// (N edges around the loop share `d`); unequal weights are checked against the
    /// dense position-only solve.
    #[test]
    fn straight_chain_loop_matches_closed_form() {
        let n = 50;
        let step = 0.7;
        let d = 0.9;
        for (odo_info, loop_info, name) in [
            (Matrix6::identity(), Matrix6::identity(), "equal weights"),
            (
                Matrix6::from_diagonal(&Vector6::new(4.0, 9.0, 1.0, 50.0, 20.0, 30.0)),
                Matrix6::from_diagonal(&Vector6::new(40.0, 2.0, 3.0, 10.0, 10.0, 10.0)),
                "unequal weights",
            ),
        ] {
            let poses = (0..n)
                .map(|k| Isometry3::translation(step * k as f64, 0.0, 0.0))
                .collect();
            let mut graph = PoseGraph::new(poses);
            graph.fixed[0] = true;
            let mut lin = Vec::new();
            let z_odo = Vector3::new(step, 0.0, 0.0);
            for k in 1..n {
                graph.add_edge(k - 1, k, Isometry3::translation(step, 0.0, 0.0), odo_info);
                lin.push((
                    k - 1,
                    k,
                    z_odo,
                    odo_info.fixed_view::<3, 3>(0, 0).into_owned(),
                ));
            }
            // Loop edge from the last pose to the first: pose 0 seen from pose n-1.
            let z_loop = Vector3::new(-(step * (n - 1) as f64 + d), 0.0, 0.0);
            graph.add_edge(
                n - 1,
                0,
                Isometry3::from_parts(z_loop.into(), UnitQuaternion::identity()),
                loop_info,
            );
            lin.push((
                n - 1,
                0,
                z_loop,
                loop_info.fixed_view::<3, 3>(0, 0).into_owned(),
            ));

            let cfg = PoseGraphConfig {
                max_iterations: 20,
                tolerance: 1e-14,
            };
            let result = graph.optimize(&cfg).expect("valid");
            assert!(result.converged, "{name}: {result:?}");
            let expected = position_only_optimum(n, &lin);
            for (k, (pose, want)) in graph.poses.iter().zip(&expected).enumerate() {
                let p = pose.translation.vector;
                assert!(
                    (p - want).norm() < 1e-9,
                    "{name}: pose {k} at {} expected {} (dense position-only solve)",
                    p.transpose(),
                    want.transpose()
                );
                assert!(
                    pose.rotation.angle() < 1e-12,
                    "{name}: pose {k} rotated by {}",
                    pose.rotation.angle()
                );
                if name == "equal weights" {
                    let linear = k as f64 * (step + d / n as f64);
                    assert!(
                        (p - Vector3::new(linear, 0.0, 0.0)).norm() < 1e-9,
                        "{name}: pose {k} at x = {} expected k (s + d/N) = {linear}",
                        p.x
                    );
                }
            }
        }
    }

    /// A seeded random walk; odometry edges from the true relative poses plus small
    /// noise, the initial guess drifted (a yaw, pitch and scale bias per step), a loop
    /// edge with the true relative pose between the last and the first pose.
    fn random_walk_problem(seed: u64, n: usize) -> (PoseGraph, Vec<Isometry3<f64>>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let (sigma_t, sigma_r) = (0.01, 0.002);
        let mut truth = vec![Isometry3::identity()];
        for k in 1..n {
            // Forward 1 m, a curve that comes around, random wiggles.
            let yaw = std::f64::consts::TAU / n as f64 + rng.random_range(-0.05..0.05);
            let step = Isometry3::from_parts(
                Translation3::new(
                    1.0,
                    rng.random_range(-0.1..0.1),
                    rng.random_range(-0.05..0.05),
                ),
                UnitQuaternion::from_euler_angles(
                    rng.random_range(-0.02..0.02),
                    rng.random_range(-0.02..0.02),
                    yaw,
                ),
            );
            truth.push(truth[k - 1] * step);
        }
        let bias = Isometry3::from_parts(
            Translation3::new(0.02, 0.01, 0.0),
            UnitQuaternion::from_euler_angles(0.0, 0.003, 0.006),
        );
        let mut drifted = vec![truth[0]];
        for k in 1..n {
            drifted.push(drifted[k - 1] * truth[k - 1].inv_mul(&truth[k]) * bias);
        }
        let mut graph = PoseGraph::new(drifted);
        graph.fixed[0] = true;
        let info = information(sigma_t, sigma_r);
        for k in 1..n {
            let noise = Isometry3::from_parts(
                Translation3::from(random_vector3(&mut rng, sigma_t)),
                UnitQuaternion::from_scaled_axis(random_vector3(&mut rng, sigma_r)),
            );
            graph.add_edge(k - 1, k, truth[k - 1].inv_mul(&truth[k]) * noise, info);
        }
        graph.add_edge(n - 1, 0, truth[n - 1].inv_mul(&truth[0]), info);
        (graph, truth)
    }

    #[test]
    fn random_walk_loop_closure_removes_drift() {
        let n = 300;
        let (mut graph, truth) = random_walk_problem(42, n);
        let (before_t, before_r) = pose_distance(&graph.poses[n - 1], &truth[n - 1]);
        let result = graph.optimize(&PoseGraphConfig::default()).expect("valid");
        let (after_t, after_r) = pose_distance(&graph.poses[n - 1], &truth[n - 1]);
        println!(
            "random walk N={n}: end pose error {before_t:.3} m / {before_r:.4} rad -> {after_t:.4} m / {after_r:.5} rad ({result:?})"
        );
        assert!(result.converged, "{result:?}");
        assert!(
            after_t * 10.0 < before_t && after_r * 10.0 < before_r,
            "end pose error {before_t:.3} m / {before_r:.4} rad -> {after_t:.4} m / {after_r:.5} rad ({result:?})"
        );
        // Every pose, not only the end, is back near the truth.
        let worst = (0..n)
            .map(|k| pose_distance(&graph.poses[k], &truth[k]).0)
            .fold(0.0, f64::max);
        assert!(
            worst < 0.1 * before_t,
            "worst pose error {worst:.4} m (end before {before_t:.3} m)"
        );
        assert!(result.final_cost < 1e-3 * result.initial_cost, "{result:?}");
    }

    /// The odometry itself drifted (edges at the drifted relative poses): only the loop
    /// edge knows better, and it pulls the end pose back.
    #[test]
    fn loop_edge_corrects_drifted_odometry() {
        let n = 1000;
        let mut graph = drifted_circle(n).expect("graph");
        let yaw_step = std::f64::consts::TAU / n as f64;
        let radius = 0.5 / yaw_step;
        let yaw = yaw_step * (n - 1) as f64;
        let truth_end = Isometry3::from_parts(
            Translation3::new(
                radius * yaw.sin(),
                radius * (1.0 - yaw.cos()),
                0.3 * (3.0 * yaw).sin(),
            ),
            UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
        );
        let (before_t, before_r) = pose_distance(&graph.poses[n - 1], &truth_end);
        let result = graph.optimize(&PoseGraphConfig::default()).expect("valid");
        let (after_t, after_r) = pose_distance(&graph.poses[n - 1], &truth_end);
        println!(
            "drifted odometry N={n}: end pose error {before_t:.3} m / {before_r:.4} rad -> {after_t:.4} m / {after_r:.5} rad ({result:?})"
        );
        assert!(result.converged, "{result:?}");
        assert!(
            after_t * 10.0 < before_t && after_r * 10.0 < before_r,
            "end pose error {before_t:.3} m / {before_r:.4} rad -> {after_t:.4} m / {after_r:.5} rad ({result:?})"
        );
    }

    #[test]
    fn errors() {
        let poses: Vec<_> = (0..3)
            .map(|k| Isometry3::translation(k as f64, 0.0, 0.0))
            .collect();
        let info = Matrix6::identity();
        let cfg = PoseGraphConfig::default();

        let mut g = PoseGraph::new(poses.clone());
        g.fixed[0] = true;
        g.add_edge(0, 3, Isometry3::identity(), info);
        assert_eq!(
            g.optimize(&cfg),
            Err(PoseGraphError::EdgeOutOfRange {
                edge: 0,
                pose: 3,
                poses: 3
            })
        );
        assert!(g.cost().is_nan());
        assert_eq!(
            g.add_current_edge(1, 7, info),
            Err(PoseGraphError::EdgeOutOfRange {
                edge: 1,
                pose: 7,
                poses: 3
            })
        );

        let mut g = PoseGraph::new(poses.clone());
        g.add_current_edge(0, 1, info).expect("in range");
        assert_eq!(
            g.optimize(&cfg),
            Err(PoseGraphError::NoFixedPose { poses: 3 })
        );

        let mut g = PoseGraph::new(poses.clone());
        g.fixed[0] = true;
        g.add_current_edge(0, 1, info).expect("in range");
        g.poses[2].translation.vector.y = f64::NAN;
        assert_eq!(
            g.optimize(&cfg),
            Err(PoseGraphError::NonFinitePose { pose: 2 })
        );

        let mut g = PoseGraph::new(poses.clone());
        g.fixed[0] = true;
        let mut bad = info;
        bad[(4, 4)] = f64::INFINITY;
        g.add_edge(0, 1, Isometry3::identity(), bad);
        assert_eq!(
            g.optimize(&cfg),
            Err(PoseGraphError::NonFiniteEdge { edge: 0 })
        );

        let mut g = PoseGraph::new(poses.clone());
        g.fixed[0] = true;
        g.add_edge(1, 1, Isometry3::identity(), info);
        assert_eq!(
            g.optimize(&cfg),
            Err(PoseGraphError::SelfEdge { edge: 0, pose: 1 })
        );

        let mut g = PoseGraph::new(poses.clone());
        g.fixed[0] = true;
        let mut negative = info;
        negative[(2, 2)] = -1.0;
        g.add_edge(0, 1, Isometry3::identity(), negative);
        let mut asymmetric = info;
        asymmetric[(0, 5)] = 0.5;
        g.add_edge(1, 2, Isometry3::identity(), asymmetric);
        assert_eq!(
            g.optimize(&cfg),
            Err(PoseGraphError::InvalidInformation { edge: 0 })
        );
        g.edges.remove(0);
        assert_eq!(
            g.optimize(&cfg),
            Err(PoseGraphError::InvalidInformation { edge: 0 })
        );

        let mut g = PoseGraph::new(poses.clone());
        g.fixed.pop();
        assert_eq!(
            g.optimize(&cfg),
            Err(PoseGraphError::FixedLength { poses: 3, fixed: 2 })
        );

        let mut g = PoseGraph::new(poses);
        g.fixed[0] = true;
        let zero = PoseGraphConfig {
            max_iterations: 0,
            ..cfg
        };
        assert!(matches!(g.optimize(&zero), Err(PoseGraphError::Config(_))));
        let nan = PoseGraphConfig {
            tolerance: f64::NAN,
            ..cfg
        };
        assert!(matches!(g.optimize(&nan), Err(PoseGraphError::Config(_))));
    }

    /// Fixed poses are untouched; a free pose with no edge stays put (damping only).
    #[test]
    fn fixed_and_unconstrained_poses_stay() {
        let (mut graph, _) = random_walk_problem(5, 100);
        graph.fixed[50] = true;
        let lonely = Isometry3::translation(100.0, 5.0, 1.0);
        graph.poses.push(lonely);
        graph.fixed.push(false);
        let before = graph.poses.clone();
        graph.optimize(&PoseGraphConfig::default()).expect("valid");
        for k in [0, 50] {
            assert_eq!(graph.poses[k], before[k], "fixed pose {k} moved");
        }
        assert_eq!(graph.poses[100], lonely);
        assert_ne!(graph.poses[99], before[99]);
    }

    fn bits(graph: &PoseGraph) -> Vec<u64> {
        graph
            .poses
            .iter()
            .flat_map(|p| {
                p.translation
                    .vector
                    .iter()
                    .chain(p.rotation.coords.iter())
                    .map(|x| x.to_bits())
                    .collect::<Vec<_>>()
            })
            .collect()
    }

    #[test]
    fn deterministic_bit_for_bit() {
        let run = || {
            let (mut graph, _) = random_walk_problem(99, 400);
            let result = graph.optimize(&PoseGraphConfig::default()).expect("valid");
            (bits(&graph), result.final_cost.to_bits(), result.iterations)
        };
        let first = run();
        let second = run();
        assert_eq!(first.1, second.1, "final cost differs");
        assert_eq!(first.2, second.2, "iterations differ");
        assert!(first.0 == second.0, "poses differ");
        let from_pool = rayon::ThreadPoolBuilder::new()
            .num_threads(3)
            .build()
            .expect("pool")
            .install(run);
        assert!(first == from_pool, "result depends on the thread pool");
    }

    /// The minimum-degree order keeps a chain closed by one loop edge at two blocks per
    /// column of L (no row filled across the chain).
    #[test]
    fn chain_with_loop_has_linear_fill() {
        let graph = drifted_circle(1000).expect("graph");
        let structure = Structure::new(&graph.fixed, &graph.edges);
        assert_eq!(structure.len(), 999);
        assert!(
            structure.blocks.n_blocks() <= 2 * 999,
            "{} off-diagonal blocks",
            structure.blocks.n_blocks()
        );
    }

    /// A serpentine over `rows` vineyard rows of `per_row` keyframes, 0.5 m apart, rows
    /// 2.5 m apart, with covisibility edges between each keyframe and the one beside it in
    /// the previous row, and a loop edge back to the start; pose 0 fixed.
    fn serpentine(rows: usize, per_row: usize) -> PoseGraph {
        let mut poses = Vec::new();
        for r in 0..rows {
            for j in 0..per_row {
                let (x, yaw) = if r % 2 == 0 {
                    (0.5 * j as f64, 0.0)
                } else {
                    (0.5 * (per_row - 1 - j) as f64, std::f64::consts::PI)
                };
                poses.push(Isometry3::from_parts(
                    Translation3::new(x, 2.5 * r as f64, 0.0),
                    UnitQuaternion::from_euler_angles(0.0, 0.0, yaw),
                ));
            }
        }
        let n = poses.len();
        let mut graph = PoseGraph::new(poses);
        graph.fixed[0] = true;
        let info = dense_information(0.02, 0.002);
        for k in 1..n {
            graph.add_current_edge(k - 1, k, info).expect("in range");
        }
        for r in 1..rows {
            for j in 0..per_row {
                // The keyframe beside it in the previous row (same x).
                let k = r * per_row + j;
                let beside = (r - 1) * per_row + (per_row - 1 - j);
                graph.add_current_edge(beside, k, info).expect("in range");
            }
        }
        graph.add_current_edge(n - 1, 0, info).expect("in range");
        graph
    }

    /// Off-diagonal blocks of the envelope (profile) of `H` in the natural order, which a
    /// profile Cholesky fills: `Σ_i (i - first neighbour of i)`.
    fn natural_profile(graph: &PoseGraph) -> usize {
        let mut first: Vec<usize> = (0..graph.poses.len()).collect();
        for e in &graph.edges {
            let (lo, hi) = (e.a.min(e.b), e.a.max(e.b));
            first[hi] = first[hi].min(lo);
        }
        first.iter().enumerate().map(|(i, &f)| i - f).sum()
    }

    /// On the serpentine the minimum-degree order fills far less than the natural order's
    /// envelope, and the drifted serpentine converges.
    #[test]
    fn serpentine_fill_and_convergence() {
        let (rows, per_row) = (10, 100);
        let mut graph = serpentine(rows, per_row);
        let structure = Structure::new(&graph.fixed, &graph.edges);
        let (fill, profile) = (structure.blocks.n_blocks(), natural_profile(&graph));
        println!(
            "serpentine {rows}x{per_row}: L has {fill} off-diagonal blocks \
             ({} Schur updates) with minimum degree, the natural envelope {profile}",
            structure.blocks.n_updates()
        );
        assert!(
            fill * 5 < profile,
            "fill {fill} vs natural envelope {profile}"
        );
        // Drift the initial guess (a yaw bias per step) and optimize.
        let bias = UnitQuaternion::from_euler_angles(0.0, 0.0, 0.002);
        let truth = graph.poses.clone();
        for k in 1..truth.len() {
            let rel = truth[k - 1].inv_mul(&truth[k]);
            graph.poses[k] =
                graph.poses[k - 1] * rel * Isometry3::from_parts(Translation3::identity(), bias);
        }
        let start = Instant::now();
        let result = graph.optimize(&PoseGraphConfig::default()).expect("valid");
        let elapsed = start.elapsed().as_secs_f64();
        let worst = truth
            .iter()
            .zip(&graph.poses)
            .map(|(t, p)| pose_distance(t, p).0)
            .fold(0.0, f64::max);
        println!(
            "serpentine {rows}x{per_row}: {:.2} ms, worst pose error {worst:.2e} m, {result:?}",
            elapsed * 1e3
        );
        assert!(result.converged, "{result:?}");
        assert!(worst < 1e-6, "worst pose error {worst:e} m ({result:?})");
    }

    #[test]
    fn bench_chain_converges() {
        let mut graph = drifted_circle(200).expect("graph");
        let result = graph.optimize(&PoseGraphConfig::default()).expect("valid");
        assert!(result.converged, "{result:?}");
        assert!(bench_chain(200).expect("valid") > 0.0);
    }

    /// `cargo test --release --lib slam::pose_graph -- --ignored --nocapture`
    #[test]
    #[ignore = "timing, run by hand"]
    fn print_bench_chain() {
        for n in [200, 1000, 5000] {
            let mut graph = drifted_circle(n).expect("graph");
            let result = graph.optimize(&PoseGraphConfig::default()).expect("valid");
            let best = (0..5)
                .map(|_| bench_chain(n).expect("valid"))
                .fold(f64::INFINITY, f64::min);
            println!(
                "pose graph chain+loop N={n}: {:.2} ms (best of 5), {} iterations, cost {:.3e} -> {:.3e}",
                best * 1e3,
                result.iterations,
                result.initial_cost,
                result.final_cost
            );
        }
    }
}
