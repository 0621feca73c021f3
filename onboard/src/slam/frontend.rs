//! The stereo front-end: ORB features of both images of a rectified pair, their stereo
//! matches and the left keypoint grid, in one call with reused buffers.

use super::ConfigError;
use super::grid::{FeatureGrid, GridConfig};
use super::image::GrayImage;
use super::orb::{Features, OrbConfig, OrbExtractor};
use super::stereo::{StereoCamera, StereoConfig, StereoMatcher, StereoMatches};
use serde::{Deserialize, Serialize};

/// Front-end settings (`[slam.features]`-style table; every key optional).
#[derive(Clone, Debug, Default, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields, default)]
pub struct FrontEndConfig {
    /// ORB extraction (the same for both images).
    pub orb: OrbConfig,
    /// Stereo matching.
    pub stereo: StereoConfig,
    /// Keypoint grid of the left image.
    pub grid: GridConfig,
    /// Extract the two images one after the other on the calling thread instead of on two
    /// rayon tasks (the result is identical either way).
    pub serial: bool,
}

impl FrontEndConfig {
    /// Checks every range.
    pub fn validate(&self) -> Result<(), ConfigError> {
        self.orb.validate()?;
        self.stereo.validate()?;
        self.grid.validate()
    }
}

/// The features of one stereo pair.
#[derive(Clone, Debug, Default)]
pub struct StereoFrame {
    /// Left image features.
    pub left: Features,
    /// Right image features.
    pub right: Features,
    /// Stereo match of each left keypoint.
    pub stereo: StereoMatches,
    /// Grid of the left keypoints.
    pub grid: FeatureGrid,
}

/// Extraction and stereo matching for one rectified camera pair.
#[derive(Clone, Debug)]
pub struct StereoFrontEnd {
    cfg: FrontEndConfig,
    left: OrbExtractor,
    right: OrbExtractor,
    matcher: StereoMatcher,
}

impl StereoFrontEnd {
    /// A front-end with a validated `cfg`.
    pub fn new(cfg: FrontEndConfig) -> Result<StereoFrontEnd, ConfigError> {
        cfg.validate()?;
        Ok(StereoFrontEnd {
            left: OrbExtractor::new(cfg.orb.clone())?,
            right: OrbExtractor::new(cfg.orb.clone())?,
            matcher: StereoMatcher::new(cfg.stereo.clone())?,
            cfg,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &FrontEndConfig {
        &self.cfg
    }

    /// The left extractor (its pyramid holds the last left image's levels).
    pub fn left_extractor(&self) -> &OrbExtractor {
        &self.left
    }

    /// Extracts both images, matches them and grids the left keypoints into `out`.
    pub fn process(
        &mut self,
        cam: &StereoCamera,
        left: &GrayImage,
        right: &GrayImage,
        out: &mut StereoFrame,
    ) {
        let (le, re) = (&mut self.left, &mut self.right);
        let (lf, rf) = (&mut out.left, &mut out.right);
        if self.cfg.serial {
            le.extract(left, lf);
            re.extract(right, rf);
        } else {
            rayon::join(|| le.extract(left, lf), || re.extract(right, rf));
        }
        self.matcher.match_pair(
            cam,
            &out.left,
            self.left.pyramid(),
            &out.right,
            self.right.pyramid(),
            &mut out.stereo,
        );
        if out.grid.size() != (self.cfg.grid.cols, self.cfg.grid.rows) {
            out.grid = FeatureGrid::new(&self.cfg.grid);
        }
        out.grid
            .assign(out.left.width, out.left.height, &out.left.keypoints);
    }
}
