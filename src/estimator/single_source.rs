//! Single-source trajectories (GNSS-only, tracking-camera-only). (Implementation pending.)
