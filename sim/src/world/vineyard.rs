//! Vineyard generation: posts, wires, vines and terrain from a seed. (Implementation pending.)

use super::World;
use crate::params::{ParamError, WorldParams};
use nalgebra::Vector3;

/// A trellis post.
#[derive(Clone, Debug, PartialEq)]
pub struct Post {
    /// Row index.
    pub row: u32,
    /// Foot of the post on the ground, world frame, m.
    pub base_in_world: Vector3<f64>,
    /// Height above ground, m.
    pub height_m: f64,
    /// Diameter, m.
    pub diameter_m: f64,
}

/// A trellis wire: a polyline through the row's posts at one height above ground.
#[derive(Clone, Debug, PartialEq)]
pub struct Wire {
    /// Row index.
    pub row: u32,
    /// Height above ground at the posts, m.
    pub height_m: f64,
    /// Attachment points on the posts, world frame, m.
    pub points_in_world: Vec<Vector3<f64>>,
}

/// A vine.
#[derive(Clone, Debug, PartialEq)]
pub struct Plant {
    /// Row index.
    pub row: u32,
    /// Planting position index along the row.
    pub slot: u32,
    /// Foot of the trunk on the ground, world frame, m.
    pub base_in_world: Vector3<f64>,
    /// Trunk height up to the cordon, m.
    pub trunk_height_m: f64,
    /// Trunk diameter, m.
    pub trunk_diameter_m: f64,
    /// Canopy height above the cordon, m.
    pub canopy_height_m: f64,
    /// Canopy width across the row, m.
    pub canopy_width_m: f64,
    /// Per-plant seed for appearance variation (leaf placement, bunches) in rendering.
    pub appearance_seed: u64,
}

/// See [`World::generate`].
pub fn generate(_seed: u64, _params: &WorldParams) -> Result<World, ParamError> {
    todo!("world generation")
}

/// See [`World::digest`].
pub fn digest(_world: &World) -> String {
    todo!("world digest")
}
