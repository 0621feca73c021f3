//! Routes: the path a robot follows, built from the row layout. (Implementation pending.)

use crate::params::{HeadlandsParams, ParamError, RouteParams};
use crate::world::RowLayout;
use nalgebra::Vector2;

/// A path in the world's horizontal plane, densely sampled, with the cumulative arc
/// length at each point.
#[derive(Clone, Debug, PartialEq)]
pub struct Route {
    /// Path points `(x, y)` in the world frame, m, about `ROUTE_SAMPLE_M` apart.
    pub points: Vec<Vector2<f64>>,
    /// Arc length from the start at each point, m.
    pub arc_length_m: Vec<f64>,
    /// Signed curvature at each point, 1/m (positive: turning left).
    pub curvature_per_m: Vec<f64>,
}

/// Builds the route a scenario's `[route]` table asks for.
pub fn build_route(
    _params: &RouteParams,
    _layout: &RowLayout,
    _headlands: &HeadlandsParams,
) -> Result<Route, ParamError> {
    todo!("route building")
}
