//! Sensor model: tracking_camera. (Implementation pending.)
