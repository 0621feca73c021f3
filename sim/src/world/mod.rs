//! The procedural vineyard: row layout, trellis posts and wires, vines, terrain.
//!
//! [`World::generate`] is a pure function of `(seed, params)`: the same inputs give the
//! same world bit for bit ([`World::digest`]). Render geometry (leaves, bunches,
//! textures) is derived from these per-instance records by the rendering layer, so a new
//! renderer adds geometry without changing the layout types.

pub mod layout;
pub mod surface;
pub mod terrain;
pub mod vineyard;

pub use layout::RowLayout;
pub use surface::{PlaneSurface, Surface, SurfacePoint};
pub use terrain::Terrain;
pub use vineyard::{Occluder, Plant, Post, TagBoard, Wire};

use crate::params::{ParamError, WorldParams};

/// A generated vineyard.
#[derive(Clone, Debug, PartialEq)]
pub struct World {
    /// The seed it was generated from.
    pub seed: u64,
    /// The parameters it was generated from.
    pub params: WorldParams,
    /// Row geometry.
    pub layout: RowLayout,
    /// The ground.
    pub terrain: Terrain,
    /// Trellis posts, row by row, in order along the row.
    pub posts: Vec<Post>,
    /// Trellis wires, one per row and wire height.
    pub wires: Vec<Wire>,
    /// Vines (missing plants are absent), row by row, in order along the row.
    pub plants: Vec<Plant>,
    /// AprilTag boards, in `[[world.tags]]` order.
    pub tags: Vec<TagBoard>,
    /// Featureless boxes, in `[[world.occluders]]` order.
    pub occluders: Vec<Occluder>,
}

impl World {
    /// Generates the vineyard for `seed`. Fails with the dotted path of the first
    /// parameter that cannot be used (e.g. `world.rows.spacing_m`).
    pub fn generate(seed: u64, params: &WorldParams) -> Result<World, ParamError> {
        vineyard::generate(seed, params)
    }

    /// SHA-256 (hex) over every generated number's bit pattern: equal digests mean
    /// bit-identical worlds.
    pub fn digest(&self) -> String {
        vineyard::digest(self)
    }
}
