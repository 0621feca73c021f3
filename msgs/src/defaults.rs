//! The embedded scenario defaults (`scenarios/defaults.toml`), the one place where every
//! default of vinebench is written down and explained.
//!
//! A scenario file is merged over these defaults (tables key by key, arrays replaced), so
//! the simulator's and the algorithms' parameter types have no defaults of their own in
//! code: their `Default` implementations read their section from here.

use serde::de::DeserializeOwned;
use thiserror::Error;

/// The text of `scenarios/defaults.toml`, compiled in.
pub const DEFAULTS_TOML: &str = include_str!("../../scenarios/defaults.toml");

/// The embedded defaults could not be read as the requested type: a bug caught by tests.
#[derive(Debug, Error)]
pub enum DefaultsError {
    /// The defaults file is not valid TOML.
    #[error("scenarios/defaults.toml is not valid TOML: {0}")]
    Parse(String),
    /// The dotted path names no table.
    #[error("scenarios/defaults.toml has no table `{0}`")]
    Missing(String),
    /// The table does not match the type.
    #[error("scenarios/defaults.toml: `{path}` does not match its type: {message}")]
    Shape {
        /// The dotted path.
        path: String,
        /// What serde said.
        message: String,
    },
}

/// The whole defaults document as a TOML table.
pub fn defaults_table() -> Result<toml::Table, DefaultsError> {
    DEFAULTS_TOML
        .parse::<toml::Table>()
        .map_err(|e| DefaultsError::Parse(e.to_string()))
}

/// Deserializes the section at a dotted path (`"sensors.imu"`) of the defaults.
pub fn section<T: DeserializeOwned>(path: &str) -> Result<T, DefaultsError> {
    let table = defaults_table()?;
    let mut value = toml::Value::Table(table);
    for key in path.split('.').filter(|k| !k.is_empty()) {
        value = match value {
            toml::Value::Table(mut t) => t
                .remove(key)
                .ok_or_else(|| DefaultsError::Missing(path.to_string()))?,
            _ => return Err(DefaultsError::Missing(path.to_string())),
        };
    }
    value
        .try_into()
        .map_err(|e: toml::de::Error| DefaultsError::Shape {
            path: path.to_string(),
            message: e.to_string(),
        })
}
