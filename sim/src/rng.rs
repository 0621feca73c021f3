//! Seeded random streams: one independent stream per named consumer.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use sha2::{Digest, Sha256};

/// The random stream of consumer `name` (`"world"`, `"sensors.imu"`, ...) under a master
/// seed. Streams are independent of each other and of the order they are created in, so
/// adding a sensor never changes another sensor's noise. ChaCha8 output is identical on
/// every platform.
pub fn stream(master_seed: u64, name: &str) -> ChaCha8Rng {
    let mut h = Sha256::new();
    h.update(b"vinebench-rng-v1\0");
    h.update(master_seed.to_le_bytes());
    h.update(name.as_bytes());
    let digest: [u8; 32] = h.finalize().into();
    ChaCha8Rng::from_seed(digest)
}

/// Random numbers addressed by index: the `i`-th value of a keyed sequence is a pure
/// function of `(key, i)` (the SplitMix64 output for state `key + i·γ`), so images can be
/// noised in parallel, in any order, with results independent of the thread count. Draw
/// the key from a [`stream`] once per image.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IndexedRng {
    key: u64,
}

/// The golden-ratio increment of SplitMix64.
const GAMMA: u64 = 0x9e37_79b9_7f4a_7c15;

impl IndexedRng {
    /// The sequence of `key`.
    pub fn new(key: u64) -> IndexedRng {
        IndexedRng { key }
    }

    /// 64 random bits at index `i`.
    #[inline(always)]
    pub fn bits(&self, i: u64) -> u64 {
        let mut z = self.key.wrapping_add(i.wrapping_mul(GAMMA));
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    /// Four standard-normal values at index `i` (one per 16 bits of [`IndexedRng::bits`],
    /// see [`normal_from_bits`]).
    #[inline(always)]
    pub fn normals4(&self, i: u64) -> [f32; 4] {
        let b = self.bits(i);
        std::array::from_fn(|k| normal_from_bits((b >> (16 * k)) as u16))
    }
}

/// Number of levels of [`normal_from_bits`].
const NORMAL_LEVELS: usize = 1 << 16;

/// `Φ⁻¹((k + ½)/2¹⁶)` for every `k`: the standard normal's quantiles at the centres of
/// 65 536 equal-probability bins.
static NORMAL_QUANTILES: std::sync::LazyLock<Box<[f32]>> = std::sync::LazyLock::new(|| {
    (0..NORMAL_LEVELS)
        .map(|k| inverse_normal_cdf((k as f64 + 0.5) / NORMAL_LEVELS as f64) as f32)
        .collect()
});

/// A standard-normal value from 16 uniform bits: the centre quantile of one of 65 536
/// equiprobable bins (inverse-transform sampling on a table). Mean 0 exactly (the table
/// is symmetric); variance 1 − 2·10⁻⁵ (the tails beyond ±4.3σ, probability 2·10⁻⁵, are
/// folded into the outermost bins). Ample for sensor noise, and a table load instead of
/// a Box-Muller or ziggurat step.
#[inline(always)]
pub fn normal_from_bits(b: u16) -> f32 {
    NORMAL_QUANTILES[usize::from(b)]
}

/// The standard normal quantile function Φ⁻¹(p) for `p` in (0, 1) (±∞ at 0 and 1, NaN
/// outside): Acklam's rational approximation, relative error below 1.2·10⁻⁹.
pub fn inverse_normal_cdf(p: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969_683_028_665_376e1,
        2.209_460_984_245_205e2,
        -2.759_285_104_469_687e2,
        1.383_577_518_672_69e2,
        -3.066_479_806_614_716e1,
        2.506_628_277_459_239,
    ];
    const B: [f64; 5] = [
        -5.447_609_879_822_406e1,
        1.615_858_368_580_409e2,
        -1.556_989_798_598_866e2,
        6.680_131_188_771_972e1,
        -1.328_068_155_288_572e1,
    ];
    const C: [f64; 6] = [
        -7.784_894_002_430_293e-3,
        -3.223_964_580_411_365e-1,
        -2.400_758_277_161_838,
        -2.549_732_539_343_734,
        4.374_664_141_464_968,
        2.938_163_982_698_783,
    ];
    const D: [f64; 4] = [
        7.784_695_709_041_462e-3,
        3.224_671_290_700_398e-1,
        2.445_134_137_142_996,
        3.754_408_661_907_416,
    ];
    if p.is_nan() || p <= 0.0 || p >= 1.0 {
        return if p == 0.0 {
            f64::NEG_INFINITY
        } else if p == 1.0 {
            f64::INFINITY
        } else {
            f64::NAN
        };
    }
    let tail = |q: f64| {
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    if p < 0.024_25 {
        tail((-2.0 * p.ln()).sqrt())
    } else if p > 1.0 - 0.024_25 {
        -tail((-2.0 * (1.0 - p).ln()).sqrt())
    } else {
        let q = p - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    #[test]
    fn streams_are_reproducible_and_distinct() {
        let a: u64 = stream(7, "sensors.imu").random();
        let b: u64 = stream(7, "sensors.imu").random();
        let c: u64 = stream(7, "sensors.gnss").random();
        let d: u64 = stream(8, "sensors.imu").random();
        assert_eq!(a, b);
        assert_ne!(a, c);
        assert_ne!(a, d);
    }

    #[test]
    fn inverse_normal_cdf_matches_known_quantiles() {
        // Φ⁻¹ at textbook points (e.g. Abramowitz & Stegun table 26.5).
        for (p, x) in [
            (0.5, 0.0),
            (0.841_344_746_068_543, 1.0),
            (0.975, 1.959_963_984_540_054),
            (0.001, -3.090_232_306_167_814),
            (1e-6, -4.753_424_308_822_899),
        ] {
            let got = inverse_normal_cdf(p);
            assert!((got - x).abs() < 1e-6, "Φ⁻¹({p}) = {got}, expected {x}");
            assert!((inverse_normal_cdf(1.0 - p) + x).abs() < 1e-6);
        }
    }

    #[test]
    fn indexed_normals_are_standard_normal_and_uncorrelated() {
        let r = IndexedRng::new(stream(3, "t").random());
        let n = 400_000u64;
        let (mut s1, mut s2, mut lag) = (0.0f64, 0.0f64, 0.0f64);
        let mut prev = 0.0f64;
        let mut within_1 = 0u64;
        for i in 0..n / 4 {
            for x in r.normals4(i) {
                let x = f64::from(x);
                s1 += x;
                s2 += x * x;
                lag += x * prev;
                prev = x;
                within_1 += u64::from(x.abs() < 1.0);
            }
        }
        let nf = n as f64;
        let (mean, var) = (s1 / nf, s2 / nf - (s1 / nf).powi(2));
        // Standard errors: mean 1/√n = 0.0016, variance √(2/n) = 0.0022.
        assert!(mean.abs() < 0.008, "mean {mean}");
        assert!((var - 1.0).abs() < 0.011, "variance {var}");
        assert!((lag / nf).abs() < 0.008, "lag-1 correlation {}", lag / nf);
        // P(|x| < 1) = 0.682 689 (σ of the fraction 0.000 74).
        let frac = within_1 as f64 / nf;
        assert!((frac - 0.682_689).abs() < 0.004, "P(|x|<1) = {frac}");
        // Same key, same index, same value; another key differs.
        assert_eq!(r.bits(12_345), IndexedRng::new(r.key).bits(12_345));
        assert_ne!(r.bits(12_345), IndexedRng::new(r.key ^ 1).bits(12_345));
    }
}
