//! The rotation arithmetic of evo 1.38.1 (`evo.core.lie_algebra`, scipy's `Rotation`), so
//! that angles agree to rounding: poses are 4×4 matrices used as read (KITTI rotations are
//! orthonormal only to the file's 7 digits), inverses take the transpose, and a rotation
//! angle is the norm of scipy's rotation vector (orthogonalised by SVD first when `R·Rᵀ`
//! is off the identity by more than 1e-12), not `acos((tr R − 1)/2)`, which differs by up
//! to 2 % on KITTI files.

use nalgebra::{Matrix3, Matrix4, Vector3};

/// A pose as evo holds it: `[[R, t], [0, 0, 0, 1]]`.
pub type Pose = Matrix4<f64>;

/// The rotation block.
pub fn rotation(p: &Pose) -> Matrix3<f64> {
    p.fixed_view::<3, 3>(0, 0).into_owned()
}

/// The translation column.
pub fn translation(p: &Pose) -> Vector3<f64> {
    p.fixed_view::<3, 1>(0, 3).into_owned()
}

/// `[[r, t], [0, 0, 0, 1]]`.
pub fn se3(r: &Matrix3<f64>, t: &Vector3<f64>) -> Pose {
    let mut p = Pose::identity();
    p.fixed_view_mut::<3, 3>(0, 0).copy_from(r);
    p.fixed_view_mut::<3, 1>(0, 3).copy_from(t);
    p
}

/// `p⁻¹` as evo computes it: `[[Rᵀ, −Rᵀt], [0, 1]]` (the transpose even when `R` is not
/// exactly orthonormal).
pub fn se3_inverse(p: &Pose) -> Pose {
    let r_inv = rotation(p).transpose();
    let t_inv = -(r_inv * translation(p));
    se3(&r_inv, &t_inv)
}

/// `p1⁻¹ · p2` (evo's `relative_se3`).
pub fn relative_se3(p1: &Pose, p2: &Pose) -> Pose {
    se3_inverse(p1) * p2
}

/// The rotation matrix of a quaternion `(w, x, y, z)` as evo builds it
/// (`transformations.quaternion_matrix`: normalised through the `√(2/n)` scaling; a
/// quaternion of norm² below 4ε gives the identity).
pub fn quaternion_matrix(w: f64, x: f64, y: f64, z: f64) -> Matrix3<f64> {
    let n = w * w + x * x + y * y + z * z;
    if n < f64::EPSILON * 4.0 {
        return Matrix3::identity();
    }
    let s = (2.0 / n).sqrt();
    let q = [w * s, x * s, y * s, z * s];
    let o = |i: usize, j: usize| q[i] * q[j];
    Matrix3::new(
        1.0 - o(2, 2) - o(3, 3),
        o(1, 2) - o(3, 0),
        o(1, 3) + o(2, 0),
        o(1, 2) + o(3, 0),
        1.0 - o(1, 1) - o(3, 3),
        o(2, 3) - o(1, 0),
        o(1, 3) - o(2, 0),
        o(2, 3) + o(1, 0),
        1.0 - o(1, 1) - o(2, 2),
    )
}

/// numpy's `allclose(a, b, atol)` element test (with its default `rtol = 1e-5`).
fn close(a: f64, b: f64, atol: f64) -> bool {
    (a - b).abs() <= atol + 1e-5 * b.abs()
}

/// evo's `is_so3`: determinant 1 and `RᵀR = I`, both to numpy's `allclose` with
/// `atol = 1e-6`.
pub fn is_so3(r: &Matrix3<f64>) -> bool {
    let rtr = r.transpose() * r;
    let eye = Matrix3::<f64>::identity();
    close(r.determinant(), 1.0, 1e-6)
        && rtr.iter().zip(eye.iter()).all(|(a, b)| close(*a, *b, 1e-6))
}

/// Why a rotation angle could not be computed (evo stops with the same reasons).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AngleError {
    /// evo's `is_so3` failed.
    #[error(
        "matrix is not a valid SO(3) group element (determinant {det:.6}, as evo's is_so3 tests it)"
    )]
    NotSo3 {
        /// Its determinant.
        det: f64,
    },
}

/// The rotation angle of `r`, rad, exactly as evo 1.38.1 computes it
/// (`so3_log_angle`: `is_so3`, then the norm of scipy's `Rotation.from_matrix(r).as_rotvec()`).
pub fn rotation_angle(r: &Matrix3<f64>) -> Result<f64, AngleError> {
    if !is_so3(r) {
        return Err(AngleError::NotSo3 {
            det: r.determinant(),
        });
    }
    // scipy ≥ 1.16: a matrix whose Gramian is off the identity (isclose, atol 1e-12) is
    // replaced by its polar factor U·Vᵀ.
    let gram = r * r.transpose();
    let eye = Matrix3::<f64>::identity();
    let orthogonal = gram
        .iter()
        .zip(eye.iter())
        .all(|(a, b)| close(*a, *b, 1e-12));
    let m = if orthogonal {
        *r
    } else {
        let svd = r.svd(true, true);
        match (svd.u, svd.v_t) {
            (Some(u), Some(v_t)) => u * v_t,
            _ => *r,
        }
    };
    // Markley's method as in scipy's `_from_matrix_orthogonal` (quaternion x, y, z, w).
    let decision = [
        m[(0, 0)],
        m[(1, 1)],
        m[(2, 2)],
        m[(0, 0)] + m[(1, 1)] + m[(2, 2)],
    ];
    let mut choice = 0;
    for (k, d) in decision.iter().enumerate().skip(1) {
        if *d > decision[choice] {
            choice = k;
        }
    }
    let mut q = [0.0f64; 4];
    if choice != 3 {
        let i = choice;
        let j = (i + 1) % 3;
        let k = (j + 1) % 3;
        q[i] = 1.0 - decision[3] + 2.0 * m[(i, i)];
        q[j] = m[(j, i)] + m[(i, j)];
        q[k] = m[(k, i)] + m[(i, k)];
        q[3] = m[(k, j)] - m[(j, k)];
    } else {
        q[0] = m[(2, 1)] - m[(1, 2)];
        q[1] = m[(0, 2)] - m[(2, 0)];
        q[2] = m[(1, 0)] - m[(0, 1)];
        q[3] = 1.0 + decision[3];
    }
    let norm = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    for v in &mut q {
        *v /= norm;
    }
    Ok(rotvec_norm(q))
}

/// The norm of scipy's `as_rotvec` of a unit quaternion `(x, y, z, w)`.
pub fn rotvec_norm(mut q: [f64; 4]) -> f64 {
    let [x, y, z, w] = q;
    let flip = w < 0.0
        || (w == 0.0 && x < 0.0)
        || (w == 0.0 && x == 0.0 && y < 0.0)
        || (w == 0.0 && x == 0.0 && y == 0.0 && z < 0.0);
    if flip {
        for v in &mut q {
            *v = -*v;
        }
    }
    let xyz = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
    let angle = 2.0 * xyz.atan2(q[3]);
    let scale = if angle <= 1e-3 {
        let a2 = angle * angle;
        2.0 + a2 / 12.0 + 7.0 * a2 * a2 / 2880.0
    } else {
        angle / (angle / 2.0).sin()
    };
    let (rx, ry, rz) = (scale * q[0], scale * q[1], scale * q[2]);
    (rx * rx + ry * ry + rz * rz).sqrt()
}

/// The rotation angle between two unit quaternions `(w, x, y, z)` as scipy's
/// `(Rotation(q_i).inv() * Rotation(q_j)).as_rotvec()` norm (RPE's all-pairs angle mode).
pub fn quaternion_delta_angle(qi: [f64; 4], qj: [f64; 4]) -> f64 {
    // scipy keeps (x, y, z, w); inv() negates the vector part.
    let p = [-qi[1], -qi[2], -qi[3], qi[0]];
    let q = [qj[1], qj[2], qj[3], qj[0]];
    let (pv, qv) = (
        Vector3::new(p[0], p[1], p[2]),
        Vector3::new(q[0], q[1], q[2]),
    );
    let r = pv * q[3] + qv * p[3] + pv.cross(&qv);
    let w = p[3] * q[3] - pv.dot(&qv);
    rotvec_norm([r.x, r.y, r.z, w])
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Rotation3, UnitQuaternion};

    #[test]
    fn angles_are_those_of_the_axis_angle_they_were_built_from() {
        for angle in [0.0, 1e-9, 1e-4, 1e-3, 0.5, 2.0, 3.1] {
            let axis = Vector3::new(0.3, -0.5, 0.8).normalize();
            let r = Rotation3::from_scaled_axis(axis * angle);
            let got = rotation_angle(r.matrix()).unwrap();
            assert!((got - angle).abs() < 1e-12, "{angle}: {got}");
            let q = UnitQuaternion::from_rotation_matrix(&r);
            let m = quaternion_matrix(q.w, q.i, q.j, q.k);
            assert!((m - r.matrix()).amax() < 1e-15);
        }
    }

    #[test]
    fn a_slightly_skewed_matrix_is_orthogonalised_first() {
        // A rotation of 0.01 rad with 1e-7 noise (KITTI's seven digits): the angle of its
        // polar factor, not of the trace.
        let r = *Rotation3::from_scaled_axis(Vector3::new(0.0, 0.0, 0.01)).matrix();
        let mut noisy = r;
        noisy[(0, 1)] += 3e-7;
        noisy[(2, 2)] -= 2e-7;
        let svd = noisy.svd(true, true);
        let polar = svd.u.unwrap() * svd.v_t.unwrap();
        let expected = Rotation3::from_matrix_unchecked(polar).angle();
        let got = rotation_angle(&noisy).unwrap();
        assert!((got - expected).abs() < 1e-12, "{got} vs {expected}");
        let trace_angle = ((noisy.trace() - 1.0) / 2.0).clamp(-1.0, 1.0).acos();
        assert!(
            (trace_angle - got).abs() > 1e-6,
            "the trace formula differs"
        );
    }

    #[test]
    fn not_a_rotation_is_an_error() {
        let r = Matrix3::new(1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.1);
        assert!(matches!(rotation_angle(&r), Err(AngleError::NotSo3 { .. })));
    }

    #[test]
    fn inverse_and_relative_pose() {
        let a = se3(
            Rotation3::from_euler_angles(0.1, -0.2, 0.7).matrix(),
            &Vector3::new(1.0, 2.0, 3.0),
        );
        let b = se3(
            Rotation3::from_euler_angles(-0.4, 0.3, 0.1).matrix(),
            &Vector3::new(-1.0, 0.5, 2.0),
        );
        assert!((se3_inverse(&a) * a - Pose::identity()).amax() < 1e-15);
        assert!((a * relative_se3(&a, &b) - b).amax() < 1e-14);
        let qa =
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rotation(&a)));
        let qb =
            UnitQuaternion::from_rotation_matrix(&Rotation3::from_matrix_unchecked(rotation(&b)));
        let d = quaternion_delta_angle([qa.w, qa.i, qa.j, qa.k], [qb.w, qb.i, qb.j, qb.k]);
        assert!((d - qa.angle_to(&qb)).abs() < 1e-12);
    }
}
