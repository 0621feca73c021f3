//! Noise processes shared by the sensor models.
//!
//! Every draw comes from the caller's seeded stream ([`crate::rng::stream`]). The
//! processes always consume the same number of draws per step whatever their σ (a σ of
//! zero still draws and multiplies by zero), so changing one noise parameter of a sensor
//! never shifts the random sequence seen by its other noise sources.

use nalgebra::Vector3;
use rand::Rng;
use rand_distr::StandardNormal;

/// One draw of N(0, 1).
pub fn standard_normal<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    rng.sample(StandardNormal)
}

/// Three independent draws of N(0, 1), in x, y, z order.
pub fn standard_normal3<R: Rng + ?Sized>(rng: &mut R) -> Vector3<f64> {
    let x = standard_normal(rng);
    let y = standard_normal(rng);
    let z = standard_normal(rng);
    Vector3::new(x, y, z)
}

/// White noise with a standard deviation per axis: N(0, diag(σ²)).
pub fn white3<R: Rng + ?Sized>(rng: &mut R, sigma: &Vector3<f64>) -> Vector3<f64> {
    standard_normal3(rng).component_mul(sigma)
}

/// A three-axis first-order Gauss-Markov process (discrete Ornstein-Uhlenbeck), one
/// independent process per axis, sampled on a fixed step `dt`.
///
/// Exact discretisation of `ẋ = −x/τ + w`: `x[k+1] = φ·x[k] + σ·√(1 − φ²)·n[k]` with
/// `φ = e^{−dt/τ}` and `n[k] ~ N(0, 1)`, so the steady-state standard deviation is `σ`
/// and the lag-`k` autocorrelation is `φᵏ` for any step size (no Euler error). A
/// correlation time of zero gives white noise with standard deviation `σ` (`φ = 0`).
///
/// [`GaussMarkov3::stationary`] starts the process in its steady state, so its
/// statistics do not depend on the time since the start.
#[derive(Clone, Debug, PartialEq)]
pub struct GaussMarkov3 {
    sigma: Vector3<f64>,
    phi: Vector3<f64>,
    drive: Vector3<f64>,
    state: Vector3<f64>,
}

impl GaussMarkov3 {
    /// A process with steady-state standard deviations `sigma` (per axis), correlation
    /// time `correlation_time_s` (s, ≥ 0; 0 = white) and step `dt_s` (s, > 0), starting
    /// at zero.
    pub fn new(sigma: Vector3<f64>, correlation_time_s: f64, dt_s: f64) -> GaussMarkov3 {
        let phi = if correlation_time_s > 0.0 {
            (-dt_s / correlation_time_s).exp()
        } else {
            0.0
        };
        let drive_factor = (1.0 - phi * phi).max(0.0).sqrt();
        GaussMarkov3 {
            sigma,
            phi: Vector3::repeat(phi),
            drive: sigma * drive_factor,
            state: Vector3::zeros(),
        }
    }

    /// Like [`GaussMarkov3::new`], but starting from a draw of the steady-state
    /// distribution N(0, diag(σ²)) (three draws from `rng`).
    pub fn stationary<R: Rng + ?Sized>(
        sigma: Vector3<f64>,
        correlation_time_s: f64,
        dt_s: f64,
        rng: &mut R,
    ) -> GaussMarkov3 {
        let mut p = GaussMarkov3::new(sigma, correlation_time_s, dt_s);
        p.state = white3(rng, &sigma);
        p
    }

    /// The current value.
    pub fn value(&self) -> &Vector3<f64> {
        &self.state
    }

    /// Steady-state standard deviation per axis.
    pub fn sigma(&self) -> &Vector3<f64> {
        &self.sigma
    }

    /// The one-step correlation coefficient `φ = e^{−dt/τ}` (the same on every axis).
    pub fn phi(&self) -> f64 {
        self.phi.x
    }

    /// Advances one step `dt` (three draws from `rng`).
    pub fn step<R: Rng + ?Sized>(&mut self, rng: &mut R) {
        let n = standard_normal3(rng);
        self.state = self.state.component_mul(&self.phi) + self.drive.component_mul(&n);
    }
}

/// Allan variance of a first-order Gauss-Markov process of variance `q` and correlation
/// time `tau` at averaging time `t`: `q·τ²/T²·(2T/τ − 3 + 4e^{−T/τ} − e^{−2T/τ})`
/// (a random walk `2qT/(3τ)` for `T ≪ τ`, white `2qτ/T` for `T ≫ τ`).
pub fn gauss_markov_allan_variance(q: f64, tau: f64, t: f64) -> f64 {
    let x = t / tau;
    if x < 1e-4 {
        return q * 2.0 * x / 3.0;
    }
    q * (2.0 * x - 3.0 + 4.0 * (-x).exp() - (-2.0 * x).exp()) / (x * x)
}

/// Ratio between neighbouring correlation times of a [`Flicker3`]'s processes.
pub const FLICKER_TAU_RATIO: f64 = 3.0;

/// Flicker (1/f) noise on three axes: the sum of first-order Gauss-Markov processes with
/// correlation times `τ_lo·3^k` up to `τ_hi`, equal variances, scaled so that the Allan
/// deviation is flat at `floor` between `10·τ_lo` and `τ_hi/10` (within −3 %/+1 %;
/// −12 %/+1 % from `3·τ_lo` to `τ_hi/3`), as a datasheet's "bias instability" floor is.
/// Started in its steady state.
#[derive(Clone, Debug, PartialEq)]
pub struct Flicker3 {
    parts: Vec<GaussMarkov3>,
    value: Vector3<f64>,
}

impl Flicker3 {
    /// The processes' correlation times for the band `[tau_lo, tau_hi]` (s).
    pub fn taus(tau_lo: f64, tau_hi: f64) -> Vec<f64> {
        let mut taus = vec![tau_lo];
        while let Some(&t) = taus.last()
            && t * FLICKER_TAU_RATIO <= tau_hi * (1.0 + 1e-9)
            && taus.len() < 64
        {
            taus.push(t * FLICKER_TAU_RATIO);
        }
        taus
    }

    /// The variance of each process that puts the Allan deviation's floor at `floor`.
    pub fn part_variance(floor: f64, tau_lo: f64, tau_hi: f64) -> f64 {
        let taus = Flicker3::taus(tau_lo, tau_hi);
        let (a, b) = (
            (10.0 * tau_lo).ln(),
            (tau_hi / 10.0).max(10.0 * tau_lo).ln(),
        );
        let n = 41;
        let mean = (0..n)
            .map(|i| {
                let t = (a + (b - a) * f64::from(i) / f64::from(n - 1)).exp();
                taus.iter()
                    .map(|&tau| gauss_markov_allan_variance(1.0, tau, t))
                    .sum::<f64>()
            })
            .sum::<f64>()
            / f64::from(n);
        floor * floor / mean
    }

    /// The model's Allan deviation at averaging time `t` (per axis).
    pub fn allan_deviation(floor: f64, tau_lo: f64, tau_hi: f64, t: f64) -> f64 {
        let q = Flicker3::part_variance(floor, tau_lo, tau_hi);
        Flicker3::taus(tau_lo, tau_hi)
            .iter()
            .map(|&tau| gauss_markov_allan_variance(q, tau, t))
            .sum::<f64>()
            .sqrt()
    }

    /// A flicker process with Allan floor `floor` over `[tau_lo, tau_hi]`, step `dt_s`,
    /// started in its steady state (three draws per process from `rng`).
    pub fn stationary<R: Rng + ?Sized>(
        floor: f64,
        tau_lo: f64,
        tau_hi: f64,
        dt_s: f64,
        rng: &mut R,
    ) -> Flicker3 {
        let sigma = Flicker3::part_variance(floor, tau_lo, tau_hi).sqrt();
        let parts: Vec<GaussMarkov3> = Flicker3::taus(tau_lo, tau_hi)
            .into_iter()
            .map(|tau| GaussMarkov3::stationary(Vector3::repeat(sigma), tau, dt_s, rng))
            .collect();
        let value = parts.iter().map(|p| *p.value()).sum();
        Flicker3 { parts, value }
    }

    /// A flicker process as [`Flicker3::stationary`], but the wander since turn-on:
    /// every process starts at zero (no draws). A sensor's bias at turn-on is its
    /// calibrated value plus a turn-on residual, which is a separate setting; started in
    /// its steady state, the sum of the processes would add a turn-on bias of its own,
    /// several times the floor (its σ grows with the band's width), that no datasheet
    /// figure stands for. The Allan deviation of a run longer than the slowest
    /// correlation time is the stationary one.
    pub fn from_turn_on(floor: f64, tau_lo: f64, tau_hi: f64, dt_s: f64) -> Flicker3 {
        let sigma = Flicker3::part_variance(floor, tau_lo, tau_hi).sqrt();
        let parts: Vec<GaussMarkov3> = Flicker3::taus(tau_lo, tau_hi)
            .into_iter()
            .map(|tau| GaussMarkov3::new(Vector3::repeat(sigma), tau, dt_s))
            .collect();
        Flicker3 {
            parts,
            value: Vector3::zeros(),
        }
    }

    /// The current value.
    pub fn value(&self) -> &Vector3<f64> {
        &self.value
    }

    /// Advances one step (three draws per process).
    pub fn step<R: Rng + ?Sized>(&mut self, rng: &mut R) {
        for p in &mut self.parts {
            p.step(rng);
        }
        self.value = self.parts.iter().map(|p| *p.value()).sum();
    }
}

#[cfg(test)]
pub(crate) mod stats {
    //! Small statistics helpers for the sensor tests.

    /// Sample mean.
    pub fn mean(x: &[f64]) -> f64 {
        x.iter().sum::<f64>() / x.len() as f64
    }

    /// Sample standard deviation (around the sample mean, n − 1).
    pub fn std(x: &[f64]) -> f64 {
        let m = mean(x);
        (x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (x.len() - 1) as f64).sqrt()
    }

    /// Sample autocorrelation at `lag` (around the sample mean).
    pub fn autocorrelation(x: &[f64], lag: usize) -> f64 {
        let m = mean(x);
        let var: f64 = x.iter().map(|v| (v - m) * (v - m)).sum();
        let cov: f64 = x
            .iter()
            .zip(&x[lag..])
            .map(|(a, b)| (a - m) * (b - m))
            .sum();
        cov / var
    }

    /// Overlapping Allan deviation of rate samples `x` taken every `dt` seconds, at the
    /// averaging time `m·dt` (IEEE Std 952 estimator on the integrated angle).
    pub fn allan_deviation(x: &[f64], dt: f64, m: usize) -> f64 {
        let mut theta = Vec::with_capacity(x.len() + 1);
        theta.push(0.0);
        let mut acc = 0.0;
        for v in x {
            acc += v * dt;
            theta.push(acc);
        }
        let n = theta.len();
        assert!(n > 2 * m + 1, "series too short for m = {m}");
        let t = m as f64 * dt;
        let sum: f64 = (0..n - 2 * m)
            .map(|k| {
                let d = theta[k + 2 * m] - 2.0 * theta[k + m] + theta[k];
                d * d
            })
            .sum();
        (sum / (2.0 * t * t * (n - 2 * m) as f64)).sqrt()
    }
}

#[cfg(test)]
mod tests {
    use super::stats::*;
    use super::*;
    use crate::rng::stream;

    fn series(p: &mut GaussMarkov3, n: usize, rng: &mut impl Rng) -> [Vec<f64>; 3] {
        let mut out = [
            Vec::with_capacity(n),
            Vec::with_capacity(n),
            Vec::with_capacity(n),
        ];
        for _ in 0..n {
            for (i, o) in out.iter_mut().enumerate() {
                o.push(p.value()[i]);
            }
            p.step(rng);
        }
        out
    }

    #[test]
    fn coarse_step_keeps_steady_state_sigma_and_exact_correlation() {
        // dt = τ: φ must be e^{-1} ≈ 0.368 (an Euler discretisation would give 0) and the
        // steady-state σ must stay σ (Euler's drive σ·√(2dt/τ) would give 1.41σ).
        // AR(1) with φ = e^{-1}, N = 50 000: std error of the lag-1 autocorrelation
        // ≈ √((1 − φ²)/N) = 0.0042; of the sample std ≈ √((1+φ²)/(2N(1−φ²))) = 0.0037
        // relative. Tolerances 0.02 and 2 % are about 5σ.
        let mut rng = stream(3, "test.gm");
        let sigma = Vector3::new(1.0, 2.0, 0.5);
        let mut p = GaussMarkov3::stationary(sigma, 1.0, 1.0, &mut rng);
        assert!((p.phi() - (-1.0f64).exp()).abs() < 1e-15);
        let s = series(&mut p, 50_000, &mut rng);
        for (i, x) in s.iter().enumerate() {
            let r1 = autocorrelation(x, 1);
            assert!((r1 - (-1.0f64).exp()).abs() < 0.02, "axis {i}: lag-1 {r1}");
            let r3 = autocorrelation(x, 3);
            assert!((r3 - (-3.0f64).exp()).abs() < 0.02, "axis {i}: lag-3 {r3}");
            let sd = std(x);
            assert!((sd / sigma[i] - 1.0).abs() < 0.02, "axis {i}: std {sd}");
        }
    }

    #[test]
    fn zero_correlation_time_is_white() {
        // τ = 0: independent samples (lag-1 autocorrelation within 5/√N of 0) with σ.
        let mut rng = stream(4, "test.gm");
        let mut p = GaussMarkov3::stationary(Vector3::repeat(0.3), 0.0, 0.01, &mut rng);
        assert_eq!(p.phi(), 0.0);
        let s = series(&mut p, 40_000, &mut rng);
        for x in &s {
            assert!(autocorrelation(x, 1).abs() < 5.0 / (40_000f64).sqrt());
            assert!((std(x) / 0.3 - 1.0).abs() < 0.02);
        }
    }

    #[test]
    fn zero_sigma_still_draws_so_streams_stay_aligned() {
        // A process with σ = 0 stays at 0 but consumes its draws: the next number from the
        // stream is the same as after a process with σ ≠ 0.
        let mut a = stream(5, "test.gm");
        let mut b = stream(5, "test.gm");
        let mut pa = GaussMarkov3::stationary(Vector3::zeros(), 2.0, 0.1, &mut a);
        let mut pb = GaussMarkov3::stationary(Vector3::repeat(1.0), 2.0, 0.1, &mut b);
        for _ in 0..10 {
            pa.step(&mut a);
            pb.step(&mut b);
        }
        assert_eq!(*pa.value(), Vector3::zeros());
        assert_eq!(a.random::<u64>(), b.random::<u64>());
    }

    #[test]
    fn flicker_allan_deviation_is_flat_at_its_floor() {
        // 200 000 steps of 1 s (55 h): the measured Allan deviation at 10, 30, 100, 300
        // and 1000 s is the floor within 15 % (the estimator's own spread at 1000 s over
        // 55 h is about 7 %), and the model's curve is flat within −3 %/+1 % from 10 s to
        // 1000 s and −12 %/+1 % from 3 s to 3333 s. A single Gauss-Markov process of σ = floor instead peaks at 0.617σ near
        // 1.89τ and falls on either side (closed form).
        let floor = 2.0;
        let (lo, hi) = (1.0, 10_000.0);
        let mut rng = stream(9, "flicker");
        let mut f = Flicker3::stationary(floor, lo, hi, 1.0, &mut rng);
        let mut x = Vec::with_capacity(200_000);
        for _ in 0..200_000 {
            x.push(f.value().x);
            f.step(&mut rng);
        }
        for t in [10usize, 30, 100, 300, 1000] {
            let a = allan_deviation(&x, 1.0, t);
            assert!((a / floor - 1.0).abs() < 0.15, "T {t} s: {a} vs {floor}");
        }
        for k in 0..=60 {
            let t = 3.0 * 10f64.powf(f64::from(k) / 20.0);
            let a = Flicker3::allan_deviation(floor, lo, hi, t) / floor;
            let band = if (10.0..=1000.0).contains(&t) {
                0.97..1.01
            } else {
                0.88..1.01
            };
            assert!(band.contains(&a), "model at {t} s: {a}");
        }
        let gm = |t: f64| gauss_markov_allan_variance(1.0, 100.0, t).sqrt();
        assert!((gm(189.3) - 0.6174).abs() < 1e-3, "{}", gm(189.3));
        assert!(gm(10.0) < 0.3 && gm(5000.0) < 0.3);
    }
}
