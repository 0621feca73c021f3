//! The SLAM map: keyframes (the rig pose at a frame with each camera's features) and
//! landmarks (world points with a descriptor and the keyframe keypoints that observe
//! them).
//!
//! Landmarks are created from stereo depth when a keyframe is inserted and culled unless
//! at least [`MIN_KEYFRAME_OBSERVATIONS`] keyframes observe them by the time two more
//! keyframes exist, or when tracking finds them in fewer than a quarter of the frames
//! they should be visible in (ORB-SLAM's `MapPointCulling`). Nothing is ever moved or
//! reindexed: a culled landmark keeps its slot, marked dead, so indices stay valid.

use super::orb::{Descriptor, KeyPoint};
use nalgebra::{Isometry3, Point3, Vector3};
use vinebench_msgs::Nanos;

/// Keyframes that must observe a landmark for it to stay (the issue's ≥ 3).
pub const MIN_KEYFRAME_OBSERVATIONS: usize = 3;

/// Found/visible ratio below which a landmark is culled (ORB-SLAM: 0.25).
pub const MIN_FOUND_RATIO: f64 = 0.25;

/// A keyframe keypoint: (keyframe, camera slot within the keyframe, keypoint index).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct KeyPointRef {
    /// Keyframe index in [`Map::keyframes`].
    pub keyframe: u32,
    /// Camera slot in [`KeyFrame::cameras`].
    pub slot: u16,
    /// Keypoint index in that camera's features.
    pub keypoint: u32,
}

/// A 3D point of the map.
#[derive(Clone, Debug)]
pub struct Landmark {
    /// Position in the SLAM's `world`, m.
    pub position: Vector3<f64>,
    /// Descriptor (of the keypoint that created it).
    pub descriptor: Descriptor,
    /// Distance from the creating camera, m, and the level of the creating keypoint:
    /// together they predict the pyramid level at another distance.
    pub ref_distance_m: f64,
    /// Pyramid level of the creating keypoint.
    pub ref_level: u8,
    /// The keyframe keypoints that observe it (one per keyframe camera at most).
    pub observations: Vec<KeyPointRef>,
    /// Keyframe that created it.
    pub created_by: u32,
    /// Frames it projected into.
    pub visible: u32,
    /// Frames it was matched (as an inlier) in.
    pub found: u32,
    /// Culled or rejected: kept only so indices stay valid.
    pub dead: bool,
}

impl Landmark {
    /// Distinct keyframes observing it.
    pub fn n_keyframes(&self) -> usize {
        let mut n = 0;
        let mut last = u32::MAX;
        // Observations are appended keyframe by keyframe, so equal keyframes are adjacent.
        for o in &self.observations {
            if o.keyframe != last {
                n += 1;
                last = o.keyframe;
            }
        }
        n
    }

    /// `found / visible` (1 before it was ever visible).
    pub fn found_ratio(&self) -> f64 {
        if self.visible == 0 {
            1.0
        } else {
            f64::from(self.found) / f64::from(self.visible)
        }
    }
}

/// One camera's part of a keyframe.
#[derive(Clone, Debug)]
pub struct KeyFrameCamera {
    /// Camera index in the rig.
    pub camera: usize,
    /// The image's stamp (cameras are free-running: it may differ from the keyframe's).
    pub stamp: Nanos,
    /// `body_from_camera` at the keyframe's stamp: the rig extrinsic composed with the
    /// body's motion between the two stamps.
    pub body_from_camera: Isometry3<f64>,
    /// Keypoints of the left image.
    pub keypoints: Vec<KeyPoint>,
    /// Their descriptors.
    pub descriptors: Vec<Descriptor>,
    /// Subpixel right-image column of each keypoint's stereo match.
    pub right_x: Vec<Option<f32>>,
    /// The landmark each keypoint observes.
    pub landmarks: Vec<Option<u32>>,
}

/// A keyframe.
#[derive(Clone, Debug)]
pub struct KeyFrame {
    /// Stamp (of the rig frame's primary camera).
    pub stamp: Nanos,
    /// Pose of the rig.
    pub world_from_body: Isometry3<f64>,
    /// Cameras with features in this keyframe.
    pub cameras: Vec<KeyFrameCamera>,
    /// Set by a loop closure or a tag: its pose is anchored to a known one.
    pub anchored: bool,
    /// It started a map (the first keyframe, or a reinitialization after a loss): local
    /// BA holds it fixed, as the gauge of the keyframes that follow.
    pub map_start: bool,
}

impl KeyFrame {
    /// Every camera's descriptors, camera by camera (its bag-of-words image).
    pub fn descriptors(&self) -> impl Iterator<Item = Descriptor> + '_ {
        self.cameras
            .iter()
            .flat_map(|c| c.descriptors.iter().copied())
    }

    /// Landmarks it observes (with repeats when two cameras see the same one).
    pub fn landmarks(&self) -> impl Iterator<Item = u32> + '_ {
        self.cameras
            .iter()
            .flat_map(|c| c.landmarks.iter().flatten().copied())
    }
}

/// Keyframes and landmarks.
#[derive(Clone, Debug, Default)]
pub struct Map {
    /// Keyframes in insertion order.
    pub keyframes: Vec<KeyFrame>,
    /// Landmarks (dead ones included, see [`Landmark::dead`]).
    pub landmarks: Vec<Landmark>,
}

impl Map {
    /// Live landmarks.
    pub fn n_live_landmarks(&self) -> usize {
        self.landmarks.iter().filter(|l| !l.dead).count()
    }

    /// Adds a landmark at `position` observed by keypoint `keypoint` of camera slot `slot`
    /// of keyframe `keyframe` (which must exist), and links the keypoint to it.
    pub fn add_landmark(
        &mut self,
        position: Vector3<f64>,
        keyframe: u32,
        slot: u16,
        keypoint: u32,
    ) -> u32 {
        let id = self.landmarks.len() as u32;
        let kf = &mut self.keyframes[keyframe as usize];
        let cam = &mut kf.cameras[slot as usize];
        let kp = cam.keypoints[keypoint as usize];
        let camera_in_world = kf.world_from_body * cam.body_from_camera * Point3::origin();
        cam.landmarks[keypoint as usize] = Some(id);
        self.landmarks.push(Landmark {
            position,
            descriptor: cam.descriptors[keypoint as usize],
            ref_distance_m: (position - camera_in_world.coords).norm(),
            ref_level: kp.level,
            observations: vec![KeyPointRef {
                keyframe,
                slot,
                keypoint,
            }],
            created_by: keyframe,
            visible: 1,
            found: 1,
            dead: false,
        });
        id
    }

    /// Links keypoint `keypoint` of `slot` of `keyframe` to landmark `id` (ignored when
    /// the keypoint already observes one).
    pub fn add_observation(&mut self, id: u32, keyframe: u32, slot: u16, keypoint: u32) {
        let cam = &mut self.keyframes[keyframe as usize].cameras[slot as usize];
        if cam.landmarks[keypoint as usize].is_some() {
            return;
        }
        cam.landmarks[keypoint as usize] = Some(id);
        self.landmarks[id as usize].observations.push(KeyPointRef {
            keyframe,
            slot,
            keypoint,
        });
    }

    /// Unlinks one observation (a BA outlier).
    pub fn remove_observation(&mut self, id: u32, at: KeyPointRef) {
        let cam = &mut self.keyframes[at.keyframe as usize].cameras[at.slot as usize];
        if cam.landmarks[at.keypoint as usize] == Some(id) {
            cam.landmarks[at.keypoint as usize] = None;
        }
        let l = &mut self.landmarks[id as usize];
        l.observations.retain(|o| *o != at);
        if l.observations.is_empty() {
            l.dead = true;
        }
    }

    /// Kills landmark `id` and unlinks every keypoint from it.
    pub fn kill(&mut self, id: u32) {
        let obs = std::mem::take(&mut self.landmarks[id as usize].observations);
        for o in obs {
            let cam = &mut self.keyframes[o.keyframe as usize].cameras[o.slot as usize];
            if cam.landmarks[o.keypoint as usize] == Some(id) {
                cam.landmarks[o.keypoint as usize] = None;
            }
        }
        self.landmarks[id as usize].dead = true;
    }

    /// ORB-SLAM's landmark culling after keyframe `newest` was inserted, over the
    /// landmarks created by the last few keyframes: dead when found in fewer than
    /// [`MIN_FOUND_RATIO`] of the frames it was visible in, or when two keyframes later
    /// fewer than [`MIN_KEYFRAME_OBSERVATIONS`] keyframes observe it. Returns how many
    /// were culled.
    pub fn cull_recent(&mut self, newest: u32, recent: &mut Vec<u32>) -> usize {
        let mut culled = 0;
        let mut keep = Vec::with_capacity(recent.len());
        for &id in recent.iter() {
            let l = &self.landmarks[id as usize];
            if l.dead {
                continue;
            }
            let age = newest.saturating_sub(l.created_by);
            if l.found_ratio() < MIN_FOUND_RATIO
                || (age >= 2 && l.n_keyframes() < MIN_KEYFRAME_OBSERVATIONS)
            {
                self.kill(id);
                culled += 1;
            } else if age < 3 {
                keep.push(id);
            }
        }
        *recent = keep;
        culled
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn keyframe(n: usize) -> KeyFrame {
        KeyFrame {
            stamp: Nanos(0),
            world_from_body: Isometry3::identity(),
            cameras: vec![KeyFrameCamera {
                camera: 0,
                stamp: Nanos(0),
                body_from_camera: Isometry3::identity(),
                keypoints: vec![
                    KeyPoint {
                        x: 0.0,
                        y: 0.0,
                        level: 1,
                        angle_rad: 0.0,
                        response: 1.0,
                        size: 31.0,
                    };
                    n
                ],
                descriptors: vec![Descriptor([0; 4]); n],
                right_x: vec![None; n],
                landmarks: vec![None; n],
            }],
            anchored: false,
            map_start: false,
        }
    }

    #[test]
    fn landmarks_need_three_keyframes_two_keyframes_after_creation() {
        let mut map = Map::default();
        for _ in 0..4 {
            map.keyframes.push(keyframe(3));
        }
        let seen_thrice = map.add_landmark(Vector3::new(0.0, 0.0, 2.0), 0, 0, 0);
        let seen_twice = map.add_landmark(Vector3::new(0.0, 0.0, 3.0), 0, 0, 1);
        assert_eq!(map.landmarks[seen_thrice as usize].ref_distance_m, 2.0);
        map.add_observation(seen_thrice, 1, 0, 0);
        map.add_observation(seen_thrice, 2, 0, 0);
        map.add_observation(seen_twice, 1, 0, 1);
        // A keypoint already linked keeps its landmark.
        map.add_observation(seen_twice, 2, 0, 0);
        assert_eq!(map.keyframes[2].cameras[0].landmarks[0], Some(seen_thrice));
        assert_eq!(map.landmarks[seen_thrice as usize].n_keyframes(), 3);
        let mut recent = vec![seen_thrice, seen_twice];
        // One keyframe after creation nothing is judged yet.
        assert_eq!(map.cull_recent(1, &mut recent), 0);
        assert_eq!(recent.len(), 2);
        assert_eq!(map.cull_recent(2, &mut recent), 1);
        assert!(map.landmarks[seen_twice as usize].dead);
        assert_eq!(map.keyframes[1].cameras[0].landmarks[1], None);
        assert_eq!(map.n_live_landmarks(), 1);
        // Three keyframes on, the survivor leaves the recent list for good.
        assert_eq!(map.cull_recent(3, &mut recent), 0);
        assert!(recent.is_empty());
        assert!(!map.landmarks[seen_thrice as usize].dead);
    }

    #[test]
    fn rarely_found_landmarks_are_culled_and_outliers_unlinked() {
        let mut map = Map::default();
        map.keyframes.push(keyframe(2));
        map.keyframes.push(keyframe(2));
        let a = map.add_landmark(Vector3::new(1.0, 0.0, 0.0), 0, 0, 0);
        let b = map.add_landmark(Vector3::new(2.0, 0.0, 0.0), 0, 0, 1);
        map.landmarks[a as usize].visible = 9;
        map.landmarks[a as usize].found = 2; // 0.22 < 0.25
        let mut recent = vec![a, b];
        assert_eq!(map.cull_recent(1, &mut recent), 1);
        assert!(map.landmarks[a as usize].dead);
        assert_eq!(map.keyframes[0].cameras[0].landmarks[0], None);
        map.add_observation(b, 1, 0, 1);
        map.remove_observation(
            b,
            KeyPointRef {
                keyframe: 1,
                slot: 0,
                keypoint: 1,
            },
        );
        assert_eq!(map.landmarks[b as usize].n_keyframes(), 1);
        assert_eq!(map.keyframes[1].cameras[0].landmarks[1], None);
        assert!(!map.landmarks[b as usize].dead);
    }
}
