//! The ground as a smooth height function `z = h(x, y)` in the world frame.

use nalgebra::{Matrix2, Vector2, Vector3};

/// Height and its first and second derivatives at one point of a surface.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct SurfacePoint {
    /// Ground height `h`, m (world z).
    pub height_m: f64,
    /// `(∂h/∂x, ∂h/∂y)`.
    pub gradient: Vector2<f64>,
    /// `[[∂²h/∂x², ∂²h/∂x∂y], [∂²h/∂y∂x, ∂²h/∂y²]]`, 1/m.
    pub hessian: Matrix2<f64>,
}

impl SurfacePoint {
    /// Unit upward normal of the surface.
    pub fn normal(&self) -> Vector3<f64> {
        Vector3::new(-self.gradient.x, -self.gradient.y, 1.0).normalize()
    }
}

/// A ground surface with continuous second derivatives (C²), so that a robot following
/// it has continuous acceleration and angular rate.
pub trait Surface {
    /// Height and derivatives at world `(x, y)`. Defined everywhere (clamped or
    /// extrapolated outside the modelled area).
    fn sample(&self, x: f64, y: f64) -> SurfacePoint;
}

/// A plane `h = z0 + gx·x + gy·y`: flat or uniformly sloped ground for tests.
#[derive(Copy, Clone, Debug, PartialEq)]
pub struct PlaneSurface {
    /// Height at the origin, m.
    pub z0_m: f64,
    /// Gradient `(∂h/∂x, ∂h/∂y)`.
    pub gradient: Vector2<f64>,
}

impl Surface for PlaneSurface {
    fn sample(&self, x: f64, y: f64) -> SurfacePoint {
        SurfacePoint {
            height_m: self.z0_m + self.gradient.x * x + self.gradient.y * y,
            gradient: self.gradient,
            hessian: Matrix2::zeros(),
        }
    }
}
