//! Generic linear-Gaussian filters in covariance form (Kalman) and information form,
//! used by the tests to show that the information form the EIF uses, with all
//! same-stamp measurements summed before one solve, gives the Kalman filter's mean and
//! covariance.

#![cfg(test)]

use nalgebra::{SMatrix, SVector};

/// Kalman filter in moment form: mean `x`, covariance `p`.
#[derive(Clone, Debug)]
pub struct LinearKf<const N: usize> {
    pub x: SVector<f64, N>,
    pub p: SMatrix<f64, N, N>,
}

impl<const N: usize> LinearKf<N> {
    /// `x ← F x`, `P ← F P Fᵀ + Q`.
    pub fn predict(&mut self, f: &SMatrix<f64, N, N>, q: &SMatrix<f64, N, N>) {
        self.x = f * self.x;
        self.p = f * self.p * f.transpose() + q;
    }

    /// One measurement `z = H x + v`, `v ~ N(0, R)`, Joseph form.
    pub fn update<const M: usize>(
        &mut self,
        h: &SMatrix<f64, M, N>,
        r: &SMatrix<f64, M, M>,
        z: &SVector<f64, M>,
    ) -> Option<()> {
        let s = h * self.p * h.transpose() + r;
        let s_inv = s.cholesky()?.inverse();
        let k = self.p * h.transpose() * s_inv;
        self.x += k * (z - h * self.x);
        let i_kh = SMatrix::<f64, N, N>::identity() - k * h;
        self.p = i_kh * self.p * i_kh.transpose() + k * r * k.transpose();
        Some(())
    }
}

/// Information filter: information matrix `lambda = P⁻¹`, information vector
/// `eta = P⁻¹ x`.
#[derive(Clone, Debug)]
pub struct LinearIf<const N: usize> {
    pub lambda: SMatrix<f64, N, N>,
    pub eta: SVector<f64, N>,
}

impl<const N: usize> LinearIf<N> {
    /// From a moment-form prior.
    pub fn from_moments(x: &SVector<f64, N>, p: &SMatrix<f64, N, N>) -> Option<Self> {
        let lambda = p.cholesky()?.inverse();
        Some(LinearIf {
            eta: lambda * x,
            lambda,
        })
    }

    /// The EIF prediction: `Λ⁻ = (F Λ⁻¹ Fᵀ + Q)⁻¹`, `η⁻ = Λ⁻ F Λ⁻¹ η`.
    pub fn predict(&mut self, f: &SMatrix<f64, N, N>, q: &SMatrix<f64, N, N>) -> Option<()> {
        let chol = self.lambda.cholesky()?;
        let p = chol.inverse();
        let x = chol.solve(&self.eta);
        let lambda = (f * p * f.transpose() + q).cholesky()?.inverse();
        self.eta = lambda * (f * x);
        self.lambda = lambda;
        Some(())
    }

    /// Adds measurements that share a stamp: `Λ += Σ Hᵢᵀ Rᵢ⁻¹ Hᵢ`, `η += Σ Hᵢᵀ Rᵢ⁻¹ zᵢ`.
    pub fn update<const M: usize>(
        &mut self,
        h: &SMatrix<f64, M, N>,
        r: &SMatrix<f64, M, M>,
        z: &SVector<f64, M>,
    ) -> Option<()> {
        let r_inv = r.cholesky()?.inverse();
        let ht_rinv = h.transpose() * r_inv;
        self.lambda += ht_rinv * h;
        self.eta += ht_rinv * z;
        Some(())
    }

    /// Mean and covariance: one Cholesky solve.
    pub fn moments(&self) -> Option<(SVector<f64, N>, SMatrix<f64, N, N>)> {
        let chol = self.lambda.cholesky()?;
        Some((chol.solve(&self.eta), chol.inverse()))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    const N: usize = 5;
    const M: usize = 2;
    type MatN = SMatrix<f64, N, N>;

    fn mat<const R: usize, const C: usize>(
        scale: f64,
    ) -> impl Strategy<Value = SMatrix<f64, R, C>> {
        proptest::collection::vec(-scale..scale, R * C)
            .prop_map(|v| SMatrix::<f64, R, C>::from_column_slice(&v))
    }

    fn spd<const D: usize>(floor: f64) -> impl Strategy<Value = SMatrix<f64, D, D>> {
        mat::<D, D>(1.0)
            .prop_map(move |a| a * a.transpose() + SMatrix::<f64, D, D>::identity() * floor)
    }

    #[derive(Clone, Debug)]
    struct Step {
        f: MatN,
        q: MatN,
        /// Measurements at this step's stamp (0, 1 or 2): (H, R, z).
        meas: Vec<(SMatrix<f64, M, N>, SMatrix<f64, M, M>, SVector<f64, M>)>,
    }

    fn step() -> impl Strategy<Value = Step> {
        let meas = (mat::<M, N>(2.0), spd::<M>(0.05), mat::<M, 1>(5.0));
        (
            mat::<N, N>(0.25).prop_map(|a| a + MatN::identity()),
            spd::<N>(0.01),
            proptest::collection::vec(meas, 0..3),
        )
            .prop_map(|(f, q, meas)| Step { f, q, meas })
    }

    fn rel_close(a: f64, b: f64, scale: f64) -> bool {
        (a - b).abs() <= 1e-9 * scale
    }

    proptest! {
        /// Information form equals covariance form on random linear-Gaussian systems:
        /// same mean and covariance after every step (relative 1e-9). Same-stamp
        /// measurements are summed into the information before one solve, the Kalman
        /// filter applies them one after another.
        #[test]
        fn information_form_equals_covariance_form(
            x0 in mat::<N, 1>(3.0),
            p0 in spd::<N>(0.1),
            steps in proptest::collection::vec(step(), 1..10),
        ) {
            let mut kf = LinearKf { x: x0, p: p0 };
            let mut inf = LinearIf::from_moments(&x0, &p0).unwrap();
            for s in &steps {
                kf.predict(&s.f, &s.q);
                inf.predict(&s.f, &s.q).unwrap();
                for (h, r, z) in &s.meas {
                    kf.update(h, r, z).unwrap();
                    inf.update(h, r, z).unwrap();
                }
                let (x, p) = inf.moments().unwrap();
                let xs = kf.x.amax().max(1.0);
                let ps = kf.p.amax();
                for i in 0..N {
                    prop_assert!(rel_close(x[i], kf.x[i], xs), "mean {} vs {}", x, kf.x);
                    for j in 0..N {
                        prop_assert!(rel_close(p[(i, j)], kf.p[(i, j)], ps), "cov {} vs {}", p, kf.p);
                    }
                }
            }
        }
    }
}
